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

    def _fetch(self, sql: str, params: list) -> list[tuple]:
        try:
            return self._store.cursor().execute(sql, params).fetchall()
        except duckdb.ConnectionException as exc:
            raise Unavailable(f"the database is not available: {exc}") from None
