"""History reads on the embedded DuckDB store.

All SQL comes from ``storage.sql`` (``DuckDBDialect``); this module only
supplies a connection (the store's per-thread cursor) and the series
catalog's loader.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import duckdb

from ..errors import Unavailable
from .memory_only import check_database_allowed
from .catalog import SeriesCatalog
from .sql import DuckDBDialect, SqlQuerier
from .duckdb_store import to_micros

if TYPE_CHECKING:
    from .duckdb_store import DuckDBStore

# DuckDB appends committed rows in commit order, so ``rowid`` only grows for
# an insert-only table (series ids do not: several writers allocate them).
# lastN over more series than this goes to the database in one query.
TAIL_MAX_SERIES = 64

_LOAD_SERIES = (
    "SELECT rowid, sid, tenant, service_path, entity_id, entity_type, attr, dataset_id FROM series "
    "WHERE rowid > ? ORDER BY rowid"
)


class DuckDBQuerier(SqlQuerier):
    def __init__(self, store: DuckDBStore):
        self._store = store
        self.dialect = DuckDBDialect()
        self.catalog = SeriesCatalog(self._load_series, store.series_generation)

    def _load_series(self, after: int) -> list[tuple]:
        return self._fetch(_LOAD_SERIES, [after])

    def raw_rows(self, sids, time, *, newest_first, limit, offset, one_per_row, attrs_per_row=1):
        """One attribute per row: try the in-memory tails first."""
        if one_per_row and (len(sids) == 1 or (newest_first and len(sids) <= TAIL_MAX_SERIES)):
            rows = self._from_tails(sids, time, newest_first, limit, offset)
            if rows is not None:
                return rows
        return super().raw_rows(
            sids, time, newest_first=newest_first, limit=limit, offset=offset,
            one_per_row=one_per_row, attrs_per_row=attrs_per_row,
        )  # fmt: skip

    def _from_tails(self, sids, time, newest_first, limit, offset) -> list[tuple] | None:
        """Each series' tail holds its own newest ``offset + limit`` rows in the
        window, so the newest ``offset + limit`` of all of them are among those;
        rows order by (time, rid) as in SQL (rid is global)."""
        start = None if time.start is None else to_micros(time.start)
        end = None if time.end is None else to_micros(time.end)
        tail = self._store.tail
        if len(sids) == 1:
            got = tail.rows(sids[0], self._load_tail, start, end, newest_first, limit, offset)
            return None if got is None else [(sids[0], *row[1:]) for row in got]
        merged = []
        for sid in sids:
            got = tail.rows(sid, self._load_tail, start, end, True, offset + limit, 0)
            if got is None:
                return None
            merged.extend((row[0], row[1], sid, row) for row in got)
        merged.sort()
        stop = len(merged) - offset
        picked = merged[max(0, stop - limit): max(0, stop)]
        return [(sid, *row[1:]) for _, _, sid, row in picked]

    def latest_geometries(self, sids, time, prefilter) -> list[tuple]:
        """The latest locations come from memory unless bounded by ``toDate``."""
        if time.start is None and time.end is None:
            return self._store.latest_geo.matching(sids, prefilter)
        return super().latest_geometries(sids, time, prefilter)

    def _load_tail(self, sid: int, n: int) -> list[tuple]:
        d = self.dialect
        return self._fetch(
            f"SELECT {d.epoch_us('t')}, rid, {d.iso_ms('t')}, kind, num, txt, js "
            f"FROM {d.samples('sid, rid, t, kind, num, txt, js')} WHERE sid = ? "
            "ORDER BY t DESC, rid DESC LIMIT ?",
            [sid, n],
        )

    def _fetch(self, sql: str, params: list) -> list[tuple]:
        check_database_allowed()
        try:
            return self._store.cursor().execute(sql, params).fetchall()
        except duckdb.ConnectionException as exc:
            raise Unavailable(f"the database is not available: {exc}") from None
