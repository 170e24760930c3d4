"""History reads on PostgreSQL: the shared renderer with PostgreSQL spelling.

Series ids are allocated by an identity column shared by every replica, so
they neither commit in id order nor without gaps (ON CONFLICT consumes ids).
The catalog therefore re-reads the whole ``series`` table whenever its row
count changes (new series are rare after warm-up); counting a small table is
cheap next to any history query.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import psycopg

from ..errors import Unavailable
from .memory_only import check_database_allowed
from ..model import Kind
from .catalog import SeriesCatalog
from .sql import Dialect, SqlQuerier, box_test

if TYPE_CHECKING:
    from .postgres_store import PostgresStore


MANY_SIDS = 256


class PostgresDialect(Dialect):
    name = "postgresql"
    placeholder = "%s"
    samples_table = "samples"

    def samples(self, columns: str) -> str:
        return "samples"

    def sid_filter(self, sids: Sequence[int]) -> tuple[str, list]:
        if len(sids) == 1:
            return "sid = %s", [sids[0]]
        # One array parameter: the index on (sid, t) serves = ANY(...).
        return "sid = ANY(%s::integer[])", [list(sids)]

    def iso_ms(self, expr: str) -> str:
        return f"""to_char({expr}, 'YYYY-MM-DD"T"HH24:MI:SS.MS"+00:00"')"""

    def epoch_us(self, expr: str) -> str:
        return f"(extract(epoch from {expr}) * 1000000)::bigint"

    def json_path(self, steps: tuple[str | int, ...]) -> object:
        return [str(step) for step in steps]

    def json_number(self, col: str, path: object) -> tuple[str, list]:
        return (
            f"CASE WHEN jsonb_typeof(({col})::jsonb #> %s::text[]) = 'number' "
            f"THEN (({col})::jsonb #>> %s::text[])::double precision END",
            [path, path],
        )

    def json_is_integer(self, col: str, path: object) -> tuple[str, list]:
        return (
            f"(jsonb_typeof(({col})::jsonb #> %s::text[]) = 'number' "
            f"AND (({col})::jsonb #>> %s::text[]) ~ '^-?[0-9]+$')",
            [path, path],
        )

    def json_present(self, col: str, path: object) -> tuple[str, list]:
        return f"coalesce(jsonb_typeof(({col})::jsonb #> %s::text[]), 'null') <> 'null'", [path]

    def regex_match(self, col: str) -> str:
        return f"{col} ~ %s"


class PostgresQuerier(SqlQuerier):
    def latest_geometries(self, sids, time, prefilter) -> list[tuple]:
        """One index probe per series (``(sid, t)`` index, newest first)
        instead of ranking every location sample."""
        if not sids:
            return []
        where, params = "", []
        if time.end is not None:
            where, params = " AND x.t <= %s", [self.dialect.time_value(time.end)]
        test, test_params = box_test(self.dialect, prefilter)
        sql = (
            "SELECT sid, geo FROM (SELECT s.sid, l.geo, l.min_lon, l.min_lat, l.max_lon, l.max_lat "
            "FROM unnest(%s::integer[]) AS s(sid) CROSS JOIN LATERAL ("
            "SELECT x.geo, x.min_lon, x.min_lat, x.max_lon, x.max_lat FROM samples x "
            f"WHERE x.sid = s.sid AND x.kind = {int(Kind.GEO)}{where} ORDER BY x.t DESC, x.rid DESC LIMIT 1) l) latest"
            f" WHERE {test}"
        )
        return self._fetch(sql, [list(sids), *params, *test_params])

    def location_candidates(self, sids, time, prefilter) -> list[int]:
        """Over many series, one scan of the located samples in the box,
        intersected here: ``sid = ANY`` of thousands of ids would be tested
        on every row of that scan."""
        if len(sids) <= MANY_SIDS or prefilter is None:
            return super().location_candidates(sids, time, prefilter)
        test, test_params = box_test(self.dialect, prefilter)
        where, params = "", []
        if time.end is not None:
            where, params = " AND t <= %s", [self.dialect.time_value(time.end)]
        wanted = set(sids)
        rows = self._fetch(
            f"SELECT DISTINCT sid FROM samples WHERE kind = {int(Kind.GEO)} AND geo IS NOT NULL AND {test}{where}",
            [*test_params, *params],
        )
        return [row[0] for row in rows if row[0] in wanted]

    def _location_seeds(self, sids, before) -> tuple[str, list]:
        """The latest geo sample before ``before``: one index probe per series."""
        return (
            "SELECT l.sid, l.rid, l.t, l.kind, l.geo, l.min_lon, l.min_lat, l.max_lon, l.max_lat "
            "FROM unnest(%s::integer[]) AS s(s_sid) CROSS JOIN LATERAL ("
            "SELECT sid, rid, t, kind, geo, min_lon, min_lat, max_lon, max_lat FROM samples "
            f"WHERE sid = s.s_sid AND t < %s AND kind = {int(Kind.GEO)} AND geo IS NOT NULL "
            "ORDER BY t DESC, rid DESC LIMIT 1) l",
            [list(sids), self.dialect.time_value(before)],
        )

    def __init__(self, store: PostgresStore):
        self._store = store
        self.dialect = PostgresDialect()
        self.catalog = SeriesCatalog(self._load_series, self._series_count)

    def _series_count(self) -> int:
        return int(self._fetch("SELECT count(*) FROM series", [])[0][0])

    def _load_series(self, position: int) -> list[tuple]:
        # No commit-ordered position exists here: load everything; the
        # catalog skips the series it already knows.
        return self._fetch(
            "SELECT sid, sid, tenant, service_path, entity_id, entity_type, attr, dataset_id FROM series ORDER BY sid",
            [],
        )

    def _fetch(self, sql: str, params: list) -> list[tuple]:
        check_database_allowed()
        try:
            with self._store.connection() as conn:
                return conn.execute(sql, params, prepare=True).fetchall()
        except psycopg.OperationalError as exc:
            raise Unavailable(f"the database is not available: {exc}") from None
