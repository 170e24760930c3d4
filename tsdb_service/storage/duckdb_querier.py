"""History reads on the embedded DuckDB store.

All SQL comes from ``storage.sql`` (``DuckDBDialect``); this module only
supplies a connection (the store's per-thread cursor) and the series
catalog's loader.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import duckdb

from ..errors import Unavailable
from .catalog import SeriesCatalog
from .sql import DuckDBDialect, SqlQuerier
from .duckdb_store import to_micros

if TYPE_CHECKING:
    from .duckdb_store import DuckDBStore

# DuckDB appends committed rows in commit order, so ``rowid`` only grows for
# an insert-only table (series ids do not: several writers allocate them).
_LOAD_SERIES = (
    "SELECT rowid, sid, tenant, service_path, entity_id, entity_type, attr FROM series "
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
        """One attribute of one series: try the in-memory tail first."""
        if len(sids) == 1 and one_per_row:
            sid = sids[0]
            tail = self._store.tail.rows(
                sid, self._load_tail,
                None if time.start is None else to_micros(time.start),
                None if time.end is None else to_micros(time.end),
                newest_first, limit, offset,
            )  # fmt: skip
            if tail is not None:
                return [(sid, rid, iso, kind, num, txt, js) for _, rid, iso, kind, num, txt, js in tail]
        return super().raw_rows(
            sids, time, newest_first=newest_first, limit=limit, offset=offset,
            one_per_row=one_per_row, attrs_per_row=attrs_per_row,
        )  # fmt: skip

    def _load_tail(self, sid: int, n: int) -> list[tuple]:
        d = self.dialect
        return self._fetch(
            f"SELECT {d.epoch_us('t')}, rid, {d.iso_ms('t')}, kind, num, txt, js "
            f"FROM {d.samples('sid, rid, t, kind, num, txt, js')} WHERE sid = ? "
            "ORDER BY t DESC, rid DESC LIMIT ?",
            [sid, n],
        )

    def _fetch(self, sql: str, params: list) -> list[tuple]:
        try:
            return self._store.cursor().execute(sql, params).fetchall()
        except duckdb.ConnectionException as exc:
            raise Unavailable(f"the database is not available: {exc}") from None
