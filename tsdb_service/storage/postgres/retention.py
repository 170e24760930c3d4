"""Retention batches on PostgreSQL (``storage.retention`` drives them).

One statement per batch picks at most N expired rows by (``tableoid``,
``ctid``), deletes them and records the newest time it deleted per series
(``rollups_expired``, from its ``RETURNING``). A session advisory lock lets
one replica run a pass at a time; the others skip theirs. Rollup batches
hold the rollup lock (``storage.rollups.LOCK``), as merges and recomputes
do.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from datetime import UTC, datetime

import psycopg

from tsdb_service.storage.columns import naive_utc
from tsdb_service.storage.postgres.dialect import PostgresDialect, int_array
from tsdb_service.storage.retention import SAVE_WATERMARK
from tsdb_service.storage.rollups import Level, expire_sql, level_delete_sql, lock_statements
from tsdb_service.storage.sql.dialect import quote_ident

PG_LOCK = 0x7473_6472  # "tsdr": one retention pass at a time across replicas


class PostgresSession:
    """One retention pass's access, on a connection of its own."""

    tables = ("samples",)

    def __init__(self, conn: psycopg.Connection, forget: Callable[[Sequence[int]], None]):
        self._conn = conn
        self._d = PostgresDialect()
        self._forget = forget

    def series(self) -> list[tuple[int, str, str]]:
        return self._conn.execute("SELECT sid, tenant, entity_type FROM series").fetchall()

    def delete_samples(self, table: str, sids: Sequence[int], cutoff: datetime, limit: int) -> int:
        """One statement: pick by (tableoid, ctid), which stays right on a
        TimescaleDB hypertable's chunks, delete, and record what expired."""
        folded = f", expired AS ({expire_sql('batch')})"
        sql = (
            f"WITH pick AS MATERIALIZED (SELECT tableoid AS tab, ctid AS tid FROM {quote_ident(table)} "
            "WHERE sid = ANY(%s::integer[]) AND t < %s LIMIT %s), "
            f"batch AS (DELETE FROM {quote_ident(table)} s USING pick WHERE s.tableoid = pick.tab "
            "AND s.ctid = pick.tid RETURNING s.sid, s.t, s.kind, s.num)"
            f"{folded} SELECT count(*) FROM batch"
        )
        with self._conn.transaction():
            row = self._conn.execute(sql, [int_array(sids), naive_utc(cutoff), limit]).fetchone()
        deleted = int(row[0]) if row else 0
        if deleted:
            self._forget(sids)
        return deleted

    def delete_rollups(self, level: Level, table: str, sids: Sequence[int], cutoff: datetime, limit: int) -> int:
        sql, params = level_delete_sql(self._d, level, table, sids, cutoff, limit)
        with self._conn.transaction():
            for lock in lock_statements(self._d):
                self._conn.execute(lock)
            return self._conn.execute(sql, params).rowcount

    def save_watermark(self, kind: str, rule: str, horizon: datetime) -> None:
        self._conn.execute(
            SAVE_WATERMARK.format(p="%s"), [kind, rule, naive_utc(horizon), naive_utc(datetime.now(UTC))]
        )


@contextmanager
def postgres_session(url: str, forget: Callable[[Sequence[int]], None]) -> Iterator[PostgresSession | None]:
    """A connection of its own holding the pass lock; None when another
    replica is running its pass. ``forget(sids)`` after a batch deleted
    samples of those series: this process's per-series memory lets go."""
    with psycopg.connect(url, autocommit=True) as conn:
        locked = conn.execute("SELECT pg_try_advisory_lock(%s)", [PG_LOCK]).fetchone()
        if not locked or not locked[0]:
            yield None
            return
        try:
            yield PostgresSession(conn, forget)
        finally:
            conn.execute("SELECT pg_advisory_unlock(%s)", [PG_LOCK])
