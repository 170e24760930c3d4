"""A store: one database behind both seams, with its life and maintenance.

Routes and the history layer see only the seams (``read``, ``write``); a
``Store`` is what a backend (``storage.duckdb``, ``storage.postgres``)
implements to serve them, plus what only operators and commands need: health,
sizes, compaction, copies, retention, the rejected notifications and the
``values`` layouts. ``storage.open_store`` makes one from settings.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable, Sequence
from contextlib import AbstractContextManager
from dataclasses import dataclass
from datetime import datetime
from typing import Any

from tsdb_service.core.backup import BackupRefused, BackupReport
from tsdb_service.core.model import RejectedNotification
from tsdb_service.parse import ValuesLayout
from tsdb_service.read import Querier
from tsdb_service.read.off_loop import T, read_off_loop
from tsdb_service.write.ops import WriteOp


class Store(ABC):
    """A database with one writer and many readers.

    Every method but ``write`` and the memory-only ones is blocking: call it
    from a worker thread, never on the event loop."""

    backend: str
    # Retention and rollups (storage/retention.py): the background worker,
    # when a policy is set, and whether rollup rows may exist.
    retention: Any = None
    rollup_presence: Any = None

    def stop_retention(self) -> None:
        """Stop the retention worker (its batch in progress finishes first);
        ``close`` calls this before anything else."""
        if self.retention is not None:
            self.retention.stop()

    @abstractmethod
    async def write(self, op: WriteOp) -> None:
        """Queue ``op`` for the group committer; return once it is committed.
        The one method to await on the event loop."""

    @abstractmethod
    def write_sync(self, ops: Sequence[WriteOp]) -> None:
        """Commit ops from a non-async caller (bulk loads, copy, tests)."""

    @abstractmethod
    def values_layout(self, tenant: str, subscription_id: str) -> ValuesLayout | None:
        """A registered ``values``-format layout, from memory; a backend
        whose memory may be stale (PostgreSQL: other replicas) reads the
        database first, which ``read`` keeps off the event loop."""

    @abstractmethod
    def layouts(self, tenant: str) -> dict[str, ValuesLayout]:
        """The tenant's registered layouts by subscription id."""

    @abstractmethod
    def all_layouts(self) -> dict[tuple[str, str], ValuesLayout]:
        """Every registered layout by (tenant, subscription id), from the database."""

    @abstractmethod
    def rejected(self, tenant: str | None, limit: int, offset: int) -> list[dict[str, Any]]:
        """Rejected notifications of one tenant, newest first; ``None``: every
        tenant (the operator's listing)."""

    @abstractmethod
    def rejected_page(
        self, tenant: str | None, limit: int, offset: int, max_bytes: int
    ) -> tuple[list[dict[str, Any]], int | None]:
        """``rejected`` paged by rendered size too: ``(rows, next offset or
        None)``; at least one row, however big (``storage.rejected.page``)."""

    @abstractmethod
    def rejected_notifications(self) -> list[RejectedNotification]:
        """Every rejected notification as stored, oldest first (for copies)."""

    @abstractmethod
    def rejected_count(self) -> int:
        """How many rejected notifications are stored, in every tenant."""

    @abstractmethod
    def deliveries(self, client_id: str, limit: int) -> list[tuple[int, int, bytes]]:
        """The newest ``limit`` MQTT deliveries recorded for ``client_id``,
        newest first, as ``(seq, packet id, digest)`` (``ingest.mqtt``).
        Queries the database; run it through ``read``, which first waits
        for every acknowledged write."""

    @abstractmethod
    def health(self) -> dict[str, Any]:
        """The ``/health`` report: ``status`` pass/fail, ``backend``, counters."""

    @abstractmethod
    def sizes(self) -> tuple[int, int, int]:
        """``(bytes on disk, rejected notifications kept, their body and
        header bytes)`` for ``/metrics``. Queries the database: off the loop."""

    @abstractmethod
    def querier(self) -> Querier:
        """The history reader (one per store, thread-safe; memory only)."""

    @abstractmethod
    def compact(self, full: bool = True) -> str:
        """Reorganise stored samples for reads now (offline maintenance);
        returns what was done, in words for an operator. DuckDB moves the hot
        rows into the sorted table (and with ``full`` rewrites it as one
        sorted run); PostgreSQL keeps samples in place in its (sid, t) index
        and has nothing to do."""

    @abstractmethod
    def copy_runs_open(self) -> list[CopyRun]:
        """The unfinished copies into this store (``copy_runs``)."""

    @abstractmethod
    def copy_run_start(self, run: CopyRun) -> None:
        """Record a copy into this store as begun."""

    @abstractmethod
    def copy_run_finish(self, source: str) -> None:
        """Record the unfinished copy from ``source`` as finished."""

    @abstractmethod
    def retention_session(self) -> AbstractContextManager[Any]:
        """A retention pass's own database access (``storage.retention.Session``),
        or None inside when another replica is running its pass."""

    @abstractmethod
    def retention_watermarks(self) -> dict[tuple[str, str], datetime]:
        """Saved retention watermarks by (table, rule), timezone-aware."""

    @abstractmethod
    def rewrite_rollups(self, statements: Sequence[tuple[str, list]]) -> list[tuple]:
        """Run rollup statements (``storage.rollup_repair``) in one
        transaction, excluding merges and deletes as a delete does; the rows
        of the last one."""

    def backup(self, path: str) -> BackupReport:
        """A consistent, checked copy of the store in the new file ``path``
        (DuckDB); a backend with its own tools refuses."""
        raise BackupRefused(
            f"{self.backend} is backed up with its own tools (pg_dump, pg_basebackup): "
            "see docs/operations.md, 'Backups'"
        )

    @abstractmethod
    def close(self) -> None:
        """Drain queued writes, commit them, checkpoint, release the database."""

    async def caught_up(self) -> None:  # noqa: B027 - a store without a log is always caught up
        """Return once every write acknowledged before the call is readable
        (a store with an ingest log applies it behind the acknowledgement)."""

    def sync(self) -> None:  # noqa: B027 - a store without a log is always caught up
        """Block until every write acknowledged so far is readable (commands,
        tests, background workers; never on the event loop)."""

    async def read(self, fn: Callable[[], T], *, memory_first: bool = True, consistent: bool = True) -> T:
        """``fn()``, awaited: the one way a route reads the store.

        ``consistent`` (the default): the read sees every write acknowledged
        before it was called (``caught_up``), so a client reads what it just
        wrote. Only the notification parser's look-up of its ``values``
        layout, and reports about the service itself, read without waiting.

        The rule: **no database call on the event loop**. A read runs first
        on the loop with ``read.off_loop.MEMORY_ONLY`` set, where it
        may use only what is in memory (series catalog, tails, latest
        locations, ``values`` layouts); its first database access raises
        ``NeedsDatabase`` instead, and the read runs again from the start in
        the threadpool. So a read memory answers costs no thread hop, and
        any other costs one. ``memory_first=False`` goes to the threadpool
        at once: for reads that always need the database, or whose work
        before the database access is too costly to do twice (geo matching).
        ``fn`` may also parse and render (it runs in the request's context,
        read budget included); it must be safe to run twice. Opening and
        closing the store (the app's lifespan) are not reads: the app runs
        them in the threadpool itself.
        """
        if consistent:
            await self.caught_up()
        return await read_off_loop(fn, memory_first)


@dataclass(frozen=True, slots=True)
class CopyRun:
    """A copy into a store, as its ``copy_runs`` table records it."""

    source: str
    base_counts: dict[str, int]  # the target's samples per tenant before the copy
    base_rejected: int
    source_samples: int
