"""A store whose writes go through the group committer, and the ingest log.

Both backends' stores are one: every write goes to one ``GroupCommitter``
(``write.committer``), whose writer threads stage and commit through the
backend's appender; where the backend keeps an ingest log (DuckDB,
``write.logged``), samples are acknowledged on the log and applied behind
it, and every other write first waits for the samples acknowledged before
it (``barrier``). Here too what both report (``/health``) and the
bookkeeping statements both run outside the writer.

This is the only module of ``storage`` that wires the write machinery:
the columns, rows and SQL below it import none of it.
"""

from __future__ import annotations

import json
import time
from abc import abstractmethod
from collections.abc import Sequence
from datetime import UTC, datetime
from typing import Any

from tsdb_service.core.errors import first_line
from tsdb_service.core.model import RejectedNotification
from tsdb_service.parse import ValuesLayout
from tsdb_service.storage.columns import naive_utc
from tsdb_service.storage.deliveries import RECENT_DELIVERIES_SQL
from tsdb_service.storage.layouts import LOAD_LAYOUTS_SQL, layouts_from_rows
from tsdb_service.storage.memory import WriterMemory
from tsdb_service.storage.rejected import INSERT_COLUMNS as REJECTED_INSERT_COLUMNS
from tsdb_service.storage.store import CopyRun, Store
from tsdb_service.write.committer import GroupCommitter
from tsdb_service.write.logged import LoggedWriter
from tsdb_service.write.ops import AppendSamples, WriteOp

POISON_WARN_S = 3600.0  # /health warns this long after a write was refused for its content


class CommittingStore(Store):
    """A store whose writes go through one ``GroupCommitter``."""

    _committer: GroupCommitter
    # What memory keeps of what the writers committed (layouts included).
    memory: WriterMemory
    # Why the last write failed when the database could not write (disk
    # full, I/O error); cleared by the next write that commits.
    _write_failure: str | None = None

    # Samples go through the ingest log when the backend keeps one
    # (``write.logged``): acknowledged there, applied behind it.
    _logged: LoggedWriter | None = None

    async def write(self, op: WriteOp) -> None:
        logged = self._logged
        if logged is None:
            await self._committer.submit(op)
        elif isinstance(op, AppendSamples):
            await logged.write(op)
        else:
            await logged.barrier()  # after every sample acknowledged before it
            await self._committer.submit(op)

    def write_sync(self, ops: Sequence[WriteOp]) -> None:
        logged = self._logged
        if logged is None:
            self._committer.submit_sync(ops)
            return
        samples = [op for op in ops if isinstance(op, AppendSamples)]
        others = [op for op in ops if not isinstance(op, AppendSamples)]
        if samples:
            logged.write_sync(samples)
        if others:
            logged.sync()
            self._committer.submit_sync(others)

    async def caught_up(self) -> None:
        if self._logged is not None:
            await self._logged.caught_up()

    def sync(self) -> None:
        if self._logged is not None:
            self._logged.sync()

    @property
    def committer(self) -> GroupCommitter:
        """The group committer (metrics observe it)."""
        return self._committer

    @property
    def ingest_log(self) -> LoggedWriter | None:
        """The ingest log samples go through, if the backend keeps one."""
        return self._logged

    def layouts(self, tenant: str) -> dict[str, ValuesLayout]:
        return self.memory.layouts.of_tenant(tenant)

    def health(self) -> dict[str, Any]:
        """``fail`` unless the writers run and the database takes writes
        (and whatever ``_health_problem`` checks), and, with an ingest log,
        while it cannot be written or applied; ``warn`` while the log holds
        damaged records set aside for an operator, or for an hour after the
        database refused a write for its content (poison); else ``pass``."""
        problem = self._health_problem()
        if problem is None and self._write_failure is not None:
            problem = "the database refuses writes: " + self._write_failure
        logged = self._logged
        if problem is None and logged is not None:
            problem = logged.problem()
        alive = self._committer.alive and (logged is None or logged.alive)
        ok = alive and problem is None and self._reachable()
        warning = logged.warning() if ok and logged is not None else None
        if warning is None and ok:
            warning = self._poison_warning()
        report: dict[str, Any] = {
            "status": "fail" if not ok else "warn" if warning is not None else "pass",
            "backend": self.backend,
            "commits": self._committer.commits,
            "writes": self._committer.ops,
        }
        if problem is not None or warning is not None:
            report["output"] = problem or warning
        return report

    def _poison_warning(self) -> str | None:
        """``warn`` for an hour after the database refused a write for its
        content (``write.committer``, poison): the service works, but an
        operator has a notification to look at in the rejected store."""
        committer = self._committer
        last = committer.last_poison
        if last is None or time.time() - last[0] > POISON_WARN_S:
            return None
        at = datetime.fromtimestamp(last[0], UTC).isoformat(timespec="seconds")
        return (
            f"{committer.poisoned} write(s) refused by the database for their content since start, the last at "
            f"{at} ({last[1][:200]}); kept in GET /v2/notify/rejected?allTenants=true"
        )

    def _health_problem(self) -> str | None:
        """A backend's own reason to fail ``/health``, worded for an operator."""
        return None

    def _reachable(self) -> bool:
        """Whether the database answers (a backend probes it if it can be away)."""
        return True

    def note_write(self, exc: BaseException | None) -> None:
        """After each commit (the writers call it): None when it went
        through, else its error. Remembers whether the database takes
        writes, for ``/health``."""
        if exc is None:
            self._write_failure = None
        elif self._is_storage_error(exc):
            self._write_failure = first_line(exc)

    @staticmethod
    @abstractmethod
    def _is_storage_error(exc: BaseException) -> bool:
        """A failure to write (full disk, I/O error), not a bad statement."""

    # -- bookkeeping statements outside the writer --------------------------------

    @abstractmethod
    def _rows(self, sql: str, params: Sequence = ()) -> list[tuple]:
        """Run one statement (``?`` placeholders) on a connection of the
        store's own, outside the writer, in autocommit; its rows, if any.
        Only for tables the writer never touches (``copy_runs``) and reads."""

    def all_layouts(self) -> dict[tuple[str, str], ValuesLayout]:
        return layouts_from_rows(self._rows(LOAD_LAYOUTS_SQL))

    def rejected_notifications(self) -> list[RejectedNotification]:
        return [
            RejectedNotification(
                tenant,
                received_at.replace(tzinfo=UTC),
                error,
                description,
                headers,
                bytes(body),
                size,
                bool(cut),
                topic,
            )
            for tenant, received_at, error, description, headers, body, size, cut, topic in self._rows(
                f"SELECT {REJECTED_INSERT_COLUMNS} FROM rejected_notifications ORDER BY id"
            )
        ]

    def rejected_count(self) -> int:
        rows = self._rows("SELECT count(*) FROM rejected_notifications")
        return int(rows[0][0])

    def deliveries(self, client_id: str, limit: int) -> list[tuple[int, int, bytes]]:
        return [
            (int(seq), int(pid), bytes(digest))
            for seq, pid, digest in self._rows(RECENT_DELIVERIES_SQL, [client_id, limit])
        ]

    def copy_runs_open(self) -> list[CopyRun]:
        rows = self._rows(
            "SELECT source, base_counts, base_rejected, source_samples FROM copy_runs WHERE finished_at IS NULL"
        )
        return [CopyRun(source, json.loads(counts), int(rejected), int(n)) for source, counts, rejected, n in rows]

    def copy_run_start(self, run: CopyRun) -> None:
        self._rows(
            "INSERT INTO copy_runs (source, started_at, base_counts, base_rejected, source_samples) "
            "VALUES (?, ?, ?, ?, ?)",
            [run.source, _utcnow(), json.dumps(run.base_counts), run.base_rejected, run.source_samples],
        )

    def copy_run_finish(self, source: str) -> None:
        self._rows("UPDATE copy_runs SET finished_at = ? WHERE source = ? AND finished_at IS NULL", [_utcnow(), source])

    def retention_watermarks(self) -> dict[tuple[str, str], datetime]:
        rows = self._rows("SELECT tbl, rule, horizon FROM retention_state")
        return {(tbl, rule): horizon.replace(tzinfo=UTC) for tbl, rule, horizon in rows}


def _utcnow() -> datetime:
    return naive_utc(datetime.now(UTC))
