"""The PostgreSQL backend, for several service processes on one database.

This module is the store's life: migrations, the connection pool readers
use, the ``values`` layouts other replicas may register, and ``/health``.
The write path is the DuckDB one: a group committer per process, whose
writer threads (``appender``) commit one transaction per group; the
writer's shared state has two owners, the ids (``ids``) and what memory
keeps (``memory``), used by the store, the writers and retention alike.
``/health`` fails while the database refuses writes for lack of space or an
I/O error, until a write succeeds again.
"""

from __future__ import annotations

import contextlib
import logging
from collections.abc import Sequence
from typing import Any

import psycopg
from psycopg_pool import ConnectionPool

from tsdb_service.core.errors import Unavailable
from tsdb_service.parse import ValuesLayout
from tsdb_service.read.off_loop import check_database_allowed
from tsdb_service.storage import rejected as rejected_store
from tsdb_service.storage.committing import CommittingStore
from tsdb_service.storage.layouts import LOAD_LAYOUTS_SQL, LayoutKey, layouts_from_rows
from tsdb_service.storage.migrations import applied_versions, load_migrations
from tsdb_service.storage.postgres.appender import PostgresAppender
from tsdb_service.storage.postgres.dialect import PostgresDialect
from tsdb_service.storage.postgres.ids import PostgresIds
from tsdb_service.storage.postgres.memory import PostgresMemory
from tsdb_service.storage.postgres.querier import PostgresQuerier
from tsdb_service.storage.postgres.retention import PostgresSession, postgres_session
from tsdb_service.storage.rejected import RejectedLimits
from tsdb_service.storage.rollups import Merger, fill_statements, lock_statements, merge
from tsdb_service.write.committer import GroupCommitter

log = logging.getLogger(__name__)

_MIGRATION_LOCK = 0x7473_6462  # "tsdb": serialises migrations across processes
# SQLSTATE classes that mean the server cannot write: insufficient resources
# (53100 disk_full...) and system errors (58030 io_error...).
_STORAGE_CLASSES = ("53", "58")
# 'values' layouts older than this are read again before use: another
# replica may have registered the subscription again with other attributes.
LAYOUTS_MAX_AGE = 10.0


def is_storage_error(exc: BaseException) -> bool:
    state = getattr(exc, "sqlstate", None) or ""
    return state[:2] in _STORAGE_CLASSES


def migrate_url(url: str) -> list[int]:
    with psycopg.connect(url) as conn:
        applied = migrate_postgres(conn)
        fold_series_changes(conn)
        return applied


# Rows of ended sessions into pid 0, in one statement: every block's sum
# stays what it was (migration 0011). Two stores folding at once: the
# second finds the rows the first deleted gone and skips them.
_FOLD_SERIES_CHANGES = (
    "WITH gone AS (DELETE FROM series_changes WHERE pid <> 0 "
    "AND pid NOT IN (SELECT pid FROM pg_stat_activity WHERE pid IS NOT NULL) RETURNING block, n) "
    "INSERT INTO series_changes AS c (block, pid, n) SELECT block, 0, sum(n) FROM gone GROUP BY block ORDER BY block "
    "ON CONFLICT (block, pid) DO UPDATE SET n = c.n + EXCLUDED.n"
)


def fold_series_changes(conn: psycopg.Connection) -> None:
    """Keep ``series_changes`` to about one row per block of series and live
    session: every writer session adds a row per block it writes."""
    with conn.transaction():
        conn.execute(_FOLD_SERIES_CHANGES)


def migrate_postgres(conn: psycopg.Connection) -> list[int]:
    """Apply pending migrations under an advisory lock, so replicas starting
    together do not race."""
    applied = []
    with conn.transaction():
        conn.execute("SELECT pg_advisory_xact_lock(%s)", [_MIGRATION_LOCK])
        done = applied_versions(conn)
        for migration in load_migrations("postgresql"):
            if migration.version in done:
                continue
            conn.execute(migration.sql)
            for statement in fill_statements(PostgresDialect(), migration.version):
                conn.execute(statement)
            conn.execute(
                "INSERT INTO schema_migrations (version, name) VALUES (%s, %s)",
                [migration.version, migration.name],
            )
            applied.append(migration.version)
    return applied


class PostgresStore(CommittingStore):
    backend = "postgresql"
    memory: PostgresMemory

    def __init__(
        self,
        url: str,
        *,
        pool_size: int = 8,
        writer_threads: int = 3,
        agg_partials_hours: int = 100_000,
        rejected_limits: RejectedLimits | None = None,
    ):
        self.url = url
        # Rejected-store bounds (storage.rejected) and what they dropped, by reason.
        self.rejected_limits = rejected_limits or RejectedLimits()
        self.rejected_dropped = dict.fromkeys(rejected_store.REASONS, 0)
        migrate_url(url)
        self.pool = ConnectionPool(url, min_size=1, max_size=pool_size, open=True, kwargs={"autocommit": True})
        self.ids = PostgresIds()
        self.memory = PostgresMemory(self.ids.sid_of)
        self._load_layouts()
        self._committer = GroupCommitter(lambda: PostgresAppender(self), name="tsdb-pg-writer", threads=writer_threads)
        self._committer.start()
        self._closed = False
        self._querier = PostgresQuerier(self, agg_partials_hours)
        self._merger = Merger(self.merge_rollups)
        self._merger.start()

    def querier(self) -> PostgresQuerier:
        return self._querier

    def series_created(self) -> int:
        """Series this process's writers created and committed (grows only)."""
        return self.ids.series_count()

    def connection(self) -> contextlib.AbstractContextManager[psycopg.Connection]:
        """A pooled connection (context manager) for reads."""
        if self._closed:
            raise Unavailable("the store is closed")
        return self.pool.connection()

    def _load_layouts(self, max_age: float = 0.0) -> None:
        """Read every registered layout from the database (at open, and
        off the event loop: see ``values_layout``), unless another thread
        read them less than ``max_age`` seconds ago (``Layouts.reload``)."""
        check_database_allowed()
        self.memory.layouts.reload(self._read_layouts, max_age)

    def _read_layouts(self) -> dict[LayoutKey, ValuesLayout]:
        with self.pool.connection() as conn:
            return layouts_from_rows(conn.execute(LOAD_LAYOUTS_SQL).fetchall())

    def values_layout(self, tenant: str, subscription_id: str) -> ValuesLayout | None:
        """From memory. Another replica may have registered the subscription
        (or registered it again with other attributes), so a miss, or layouts
        read over ``LAYOUTS_MAX_AGE`` ago, read them again first: a database
        call, which on the event loop raises ``NeedsDatabase`` instead, and
        ``Store.read`` re-runs the parse in the threadpool."""
        layouts = self.memory.layouts
        layout = layouts.get(tenant, subscription_id)
        if layout is None:
            self._load_layouts()
            layout = layouts.get(tenant, subscription_id)
        elif layouts.age() > LAYOUTS_MAX_AGE:
            self._load_layouts(LAYOUTS_MAX_AGE)
            layout = layouts.get(tenant, subscription_id)
        return layout

    def layouts(self, tenant: str) -> dict[str, ValuesLayout]:
        """Read again first: another replica may have registered some."""
        self._load_layouts()
        return super().layouts(tenant)

    def rejected(self, tenant: str | None, limit: int, offset: int) -> list[dict[str, Any]]:
        where, params = ("", []) if tenant is None else ("WHERE tenant = %s ", [tenant])
        with self.connection() as conn:
            rows = conn.execute(
                f"SELECT {rejected_store.COLUMNS} FROM rejected_notifications {where}"
                "ORDER BY id DESC LIMIT %s OFFSET %s",
                [*params, limit, offset],
            ).fetchall()
        return [rejected_store.rejected_row(*row) for row in rows]

    def rejected_page(
        self, tenant: str | None, limit: int, offset: int, max_bytes: int
    ) -> tuple[list[dict[str, Any]], int | None]:
        """``rejected`` paged by size too: (rows, next offset or None)."""
        with self.connection() as conn:
            return rejected_store.page(
                lambda sql, params: conn.execute(sql, params).fetchall(),
                rejected_store.POSTGRES,
                tenant,
                limit,
                offset,
                max_bytes,
                rejected_store.rejected_row,
            )

    def _reachable(self) -> bool:
        try:
            with self.pool.connection(timeout=2) as conn:
                conn.execute("SELECT 1")
        except Exception as exc:  # report, do not raise: this is the health probe
            log.warning("database unreachable: %s", exc)
            return False
        return True

    _is_storage_error = staticmethod(is_storage_error)

    def _rows(self, sql: str, params: Sequence = ()) -> list[tuple]:
        with self.connection() as conn:
            cur = conn.execute(sql.replace("?", "%s"), list(params))
            return cur.fetchall() if cur.description is not None else []

    def compact(self, full: bool = True) -> str:
        """Nothing to do for samples: they stay where they were written, and
        the (sid, t) index already serves every read in order. Hot rollup
        rows are merged (as the merger thread does every few seconds)."""
        while self.merge_rollups(100_000):
            pass
        return "nothing to compact: PostgreSQL keeps samples in place (only DuckDB files are compacted)"

    def rewrite_rollups(self, statements: Sequence[tuple[str, list]]) -> list[tuple]:
        """One transaction on a pooled connection; the statements take the
        rollup lock themselves (``storage.rollups.lock_statements``)."""
        with self.connection() as conn, conn.transaction():
            rows: list[tuple] = []
            for sql, params in statements:
                cur = conn.execute(sql, params)
                rows = cur.fetchall() if cur.description is not None else []
            return rows

    def merge_rollups(self, limit: int) -> int:
        """At most ``limit`` hot rollup rows into their levels, in one
        transaction under the rollup lock (``storage.rollups``); how many."""
        dialect = PostgresDialect()
        with self.connection() as conn, conn.transaction():
            for sql in lock_statements(dialect):
                conn.execute(sql)

            def run(sql: str, params: list) -> list[tuple]:
                cur = conn.execute(sql, params)
                return cur.fetchall() if cur.description is not None else []

            return merge(dialect, run, limit)

    def retention_session(self) -> contextlib.AbstractContextManager[PostgresSession | None]:
        """A connection of its own holding the cluster-wide pass lock."""
        return postgres_session(self.url, self.memory.forget)

    def sizes(self) -> tuple[int, int, int]:
        with self.connection() as conn:
            size = conn.execute("SELECT pg_database_size(current_database())").fetchone()
            counted = conn.execute(
                "SELECT count(*), coalesce(sum(octet_length(body) + octet_length(headers)), 0) "
                "FROM rejected_notifications"
            ).fetchone()
        assert size is not None and counted is not None  # aggregates always return one row
        return int(size[0]), int(counted[0]), int(counted[1])

    def close(self) -> None:
        if self._closed:
            return
        self.stop_retention()
        self._merger.stop()
        self._committer.close()
        self._closed = True
        self._querier.close()
        self.pool.close()
