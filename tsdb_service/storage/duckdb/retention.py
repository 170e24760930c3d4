"""Retention batches on DuckDB (``storage.retention`` drives them).

A batch holds the compactor's lock (as a user's delete does), so it never
races the compactor moving, rewriting or merging the same rows; it picks at
most N expired rows by ``rowid``, records the newest time it deletes per
series (``rollups_expired``), deletes them, and drops the touched series
from the in-memory per-series memories and recomputes their latest
locations (``DuckDBMemory.forget``, ``relocate``). Rollup rows go by level,
under the same lock.
"""

from __future__ import annotations

import contextlib
from collections.abc import Sequence
from datetime import UTC, datetime
from typing import Any, Protocol

import duckdb

from tsdb_service.core.model import Kind
from tsdb_service.storage.columns import naive_utc
from tsdb_service.storage.duckdb.dialect import DuckDBDialect
from tsdb_service.storage.duckdb.latest_geo import LATEST_GEO_SQL
from tsdb_service.storage.duckdb.memory import DuckDBMemory
from tsdb_service.storage.retention import SAVE_WATERMARK
from tsdb_service.storage.rollups import Level, expire_sql, level_delete_sql
from tsdb_service.storage.sql.dialect import quote_ident


def _one(cur: duckdb.DuckDBPyConnection, sql: str, params: object = None) -> tuple:
    """The one row ``sql`` returns (an aggregate, a DELETE's count)."""
    rows = cur.execute(
        sql, params
    ).fetchall()  # not fetchone: an open result holds back checkpoints (connection.scalar)
    assert len(rows) == 1, sql
    return rows[0]


class RetainedStore(Protocol):
    """What a batch needs of the store (``DuckDBStore`` is one)."""

    memory: DuckDBMemory

    def compactor_lock(self) -> contextlib.AbstractContextManager[Any]: ...


class DuckDBSession:
    """One retention pass's access, on a cursor of its own."""

    tables = ("samples", "samples_hot")

    def __init__(self, store: RetainedStore, cur: duckdb.DuckDBPyConnection):
        self._store = store
        self._cur = cur
        self._d = DuckDBDialect()

    def series(self) -> list[tuple[int, str, str]]:
        return self._cur.execute("SELECT sid, tenant, entity_type FROM series").fetchall()

    def delete_samples(self, table: str, sids: Sequence[int], cutoff: datetime, limit: int) -> int:
        """One batch, under the compactor's lock: pick, record, delete, commit."""
        cur = self._cur
        where, params = self._d.sid_filter(sids)
        with self._store.compactor_lock():
            cur.execute("BEGIN")
            try:
                cur.execute(
                    "CREATE OR REPLACE TEMP TABLE retention_batch AS SELECT rowid AS r, rid, sid, t, kind, num "
                    f"FROM {quote_ident(table)} WHERE {where} AND t < ? LIMIT ?",
                    [*params, naive_utc(cutoff), limit],
                )
                n, upto = _one(cur, "SELECT count(*), max(rid) FROM retention_batch")
                if n:
                    cur.execute(expire_sql("retention_batch"))
                    cur.execute(f"DELETE FROM {quote_ident(table)} WHERE rowid IN (SELECT r FROM retention_batch)")
                cur.execute("COMMIT")
            except BaseException:
                with contextlib.suppress(duckdb.Error):  # no transaction open
                    cur.execute("ROLLBACK")
                raise
        if n:
            self._forget(upto)
        return int(n)

    def _forget(self, upto_rid: int) -> None:
        """The in-memory per-series memories and latest locations must not
        show deleted rows."""
        memory = self._store.memory
        cur = self._cur
        sids = [r[0] for r in cur.execute("SELECT DISTINCT sid FROM retention_batch").fetchall()]
        memory.forget(sids)
        geo = [
            r[0]
            for r in cur.execute(f"SELECT DISTINCT sid FROM retention_batch WHERE kind = {int(Kind.GEO)}").fetchall()
        ]
        if geo:
            query = LATEST_GEO_SQL.format(where="AND sid IN (SELECT unnest(?::INTEGER[]))")
            memory.relocate(geo, upto_rid, lambda s: cur.execute(query, [s]).fetchall())

    def delete_rollups(self, level: Level, table: str, sids: Sequence[int], cutoff: datetime, limit: int) -> int:
        sql, params = level_delete_sql(self._d, level, table, sids, cutoff, limit)
        with self._store.compactor_lock():  # merges and user deletes touch rollups under it too
            return int(_one(self._cur, sql, params)[0])

    def save_watermark(self, kind: str, rule: str, horizon: datetime) -> None:
        self._cur.execute(SAVE_WATERMARK.format(p="?"), [kind, rule, naive_utc(horizon), naive_utc(datetime.now(UTC))])
