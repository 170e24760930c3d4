"""The embedded DuckDB backend: one file, one writer, many readers.

This module is the store's life: opening the file and loading what memory
keeps of it, reads through per-thread cursors, and the reopen after a storage
failure. The writer is ``appender``, the sorter ``compactor``, the file
``connection``; the writer's shared state has two owners, the ids it hands
out (``ids``) and what memory keeps (``memory``), which the store, the
writer, retention and the ingest log all use through their public methods.

Writes are appended to ``samples_hot`` in arrival order by the group
committer. A compactor thread moves the hot rows into ``samples`` sorted by
(series, time), so a one-series query touches only the row groups whose
min/max statistics contain that series; every few moves it rewrites
``samples`` as one sorted run. Readers use per-thread cursors over
``samples_all`` (both tables) and so always see every committed sample.

A full disk can make DuckDB invalidate the database: when the automatic
checkpoint after a commit cannot write the file, the commit is durable (it is
in the WAL) but every later call fails until the file is reopened. The store
acknowledges such a commit, answers 503 meanwhile (reads included), reports
the state on ``/health`` and reopens the file in the background, with
backoff, as soon as it can (``DuckDBStore``'s lifecycle section, ``Gate``).
"""

from __future__ import annotations

import contextlib
import logging
import threading
from collections.abc import Iterator, Sequence
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import duckdb
import orjson

from tsdb_service.core.backup import BackupRefused, BackupReport
from tsdb_service.core.config import WAL_CHECKPOINT_BYTES
from tsdb_service.core.errors import Unavailable, first_line
from tsdb_service.core.model import EntitySample, RejectedNotification
from tsdb_service.parse import ValuesLayout
from tsdb_service.storage import rejected as rejected_store
from tsdb_service.storage.committing import CommittingStore
from tsdb_service.storage.duckdb.appender import DuckDBAppender
from tsdb_service.storage.duckdb.backup import take_backup
from tsdb_service.storage.duckdb.compactor import Compactor
from tsdb_service.storage.duckdb.connection import (
    LOG_SUFFIX,
    NOTHING_STORED,
    REOPEN_DELAY_S,
    REOPEN_MAX_DELAY_S,
    Gate,
    connect,
    fatal_kind,
    file_bytes,
    is_storage_error,
    migrate_duckdb,
    scalar,
    tables_max,
)
from tsdb_service.storage.duckdb.ids import SeriesIds
from tsdb_service.storage.duckdb.latest_geo import LATEST_GEO_SQL, LatestGeo
from tsdb_service.storage.duckdb.memory import DuckDBMemory
from tsdb_service.storage.duckdb.querier import DuckDBQuerier
from tsdb_service.storage.duckdb.retention import DuckDBSession
from tsdb_service.storage.duckdb.state import NO_LEGACY_SQL, StoreState, load_state, log_position
from tsdb_service.storage.layouts import LOAD_LAYOUTS_SQL, layouts_from_rows
from tsdb_service.storage.rejected import RejectedLimits
from tsdb_service.write.committer import GroupCommitter
from tsdb_service.write.log import IngestLog
from tsdb_service.write.logged import MAX_LAG_BYTES, LoggedWriter
from tsdb_service.write.ops import LogPosition, RecordRejected

log = logging.getLogger(__name__)


class DuckDBStore(CommittingStore):
    backend = "duckdb"
    memory: DuckDBMemory

    def __init__(
        self,
        path: str,
        *,
        compact_rows: int = 500_000,
        major_compact_runs: int = 8,
        writer_threads: int = 1,
        tail_series: int = 8192,
        tail_rows: int = 128,
        tail_samples: int | None = None,
        agg_partials_hours: int = 100_000,
        checkpoint_bytes: int = WAL_CHECKPOINT_BYTES,
        reopen_delay: float | None = None,
        reopen_max_delay: float | None = None,
        rejected_limits: RejectedLimits | None = None,
        ingest_log: bool = True,
        ingest_log_lag_bytes: int = MAX_LAG_BYTES,
    ):
        self.path = path
        # Rejected-store bounds (storage.rejected) and what they dropped, by reason.
        self.rejected_limits = rejected_limits or RejectedLimits()
        self.rejected_dropped = dict.fromkeys(rejected_store.REASONS, 0)
        self._checkpoint_bytes = checkpoint_bytes
        self._compact_args = (compact_rows, major_compact_runs)
        self._reopen_delays = (reopen_delay or REOPEN_DELAY_S, reopen_max_delay or REOPEN_MAX_DELAY_S)
        self._local = threading.local()
        self._gate = Gate()
        # Set while the database instance is invalid (why), cleared by a reopen.
        self._broken: str | None = None
        self._lifecycle = threading.Lock()
        self._reopening = False
        self._reopener: threading.Thread | None = None
        self._stop_reopen = threading.Event()
        self.reopens = 0
        self._backing_up = threading.Lock()  # one backup at a time
        self._generation = 0  # grows with every reopen: cursors of older ones are closed
        self.ids = SeriesIds()
        self.state: StoreState  # the database's id and ingest-log position, as the file had them at open
        # Aggregate partials (storage.partials) need row ids growing in commit order: one writer.
        partials_hours = agg_partials_hours if writer_threads == 1 else 0
        self.memory = DuckDBMemory(tail_series, tail_rows, tail_samples, partials_hours)
        self._con = connect(path, checkpoint_bytes=checkpoint_bytes)
        migrate_duckdb(self._con)
        self._load_state(self._con)
        self._compactor = Compactor(self._con, *self._compact_args, on_error=self.notice)
        self._committer = GroupCommitter(lambda: DuckDBAppender(self), threads=writer_threads)
        self._committer.start()
        self._compactor.start()
        self._closed = False
        self._querier: DuckDBQuerier | None = None
        if ingest_log and path != ":memory:":
            self._logged = self._ingest_log(path + LOG_SUFFIX, ingest_log_lag_bytes)

    # -- the ingest log (write.logged): samples acknowledged there, applied here ----------

    def _ingest_log(self, directory: str, max_lag_bytes: int) -> LoggedWriter:
        """Open the log (refusing one that is not this database's: ``LogRefused``)
        and queue what the database lacks of it."""
        state = self.state
        try:
            log_ = IngestLog(
                directory,
                state.database_id.bytes,
                applied_seq=state.position.seq,
                accept_legacy=state.legacy_log,
            )
            logged = LoggedWriter(
                log_,
                apply=self._committer.submit_sync,
                allocate_rids=self.ids.take_rids,
                applied=self._log_position,
                reject=self._keep_unappliable,
                healthy=lambda: self._broken is None and self._write_failure is None,
                seen_rid=self.ids.saw_rid,
                max_lag_bytes=max_lag_bytes,
            )
            logged.start()
            # Segments without identity are accepted until none is left: a
            # replay that left any has records to apply (the applier is busy
            # with them, and this waits for the next start); else it is idle.
            if state.legacy_log and not log_.has_legacy():
                self._rows(NO_LEGACY_SQL)
        except BaseException:
            self.close()
            raise
        return logged

    def _log_position(self) -> LogPosition:
        """How much of the ingest log the file holds (``state``)."""
        with self.reading():
            cur = self._con.cursor()
            try:
                return log_position(cur)
            finally:
                cur.close()

    def _keep_unappliable(self, entity: EntitySample, reason: str) -> None:
        body = orjson.dumps(entity)
        rejected = RejectedNotification(
            entity.tenant, datetime.now(UTC), "NotApplied", f"acknowledged but refused by the database: {reason}",
            "{}", body,
        )  # fmt: skip
        self._committer.submit_sync([RecordRejected(rejected)])

    def _load_state(self, con: duckdb.DuckDBPyConnection) -> None:
        """What the store keeps in memory, from the file: its identity and
        ingest-log position, the series ids, the next ids to hand out (never
        lower than ones already handed out or applied), the 'values' layouts
        and each series' latest location; no tails,
        partials or latest instances yet (they load on demand)."""
        series = {
            tuple(row[1:]): row[0]
            for row in con.execute(
                "SELECT sid, tenant, service_path, entity_id, entity_type, attr FROM series"
            ).fetchall()
        }
        max_rid = tables_max(con, "rid")
        max_iid = tables_max(con, "iid")
        max_rejected = scalar(con, "SELECT max(id) FROM rejected_notifications") or 0
        layouts = layouts_from_rows(con.execute(LOAD_LAYOUTS_SQL).fetchall())
        latest_geo = LatestGeo(con.execute(LATEST_GEO_SQL.format(where="")).fetchall())
        self.state = load_state(con)
        # Row ids never go back below one applied, even if deletes removed its rows.
        self.ids.load(series, max(max_rid, self.state.position.rid), max_iid, max_rejected)
        self.memory.fresh(latest_geo, layouts)

    # -- history reads (storage.duckdb.querier) ------------------------------------

    def querier(self) -> DuckDBQuerier:
        if self._querier is None:
            self._querier = DuckDBQuerier(self)
        return self._querier

    def series_generation(self) -> int:
        """Grows whenever the writer publishes new series (after commit)."""
        return self.ids.series_count()

    # -- reads ---------------------------------------------------------------

    def cursor(self) -> duckdb.DuckDBPyConnection:
        """A cursor for the calling thread: DuckDB connections are not
        thread-safe, cursors (child connections) are cheap and reusable.
        A reopen closes them all, so a thread makes a new one after it."""
        if self._closed:
            raise Unavailable("the store is closed")
        if self._broken is not None:
            raise Unavailable(self._unavailable_reason())
        local = self._local
        if getattr(local, "generation", None) != self._generation:
            local.cursor = self._con.cursor()
            local.generation = self._generation
        return local.cursor

    @contextlib.contextmanager
    def reading(self) -> Iterator[None]:
        """Hold while using ``cursor()``: a reopen waits for it."""
        with self._gate.use(self._unavailable_reason()):
            yield

    # -- the writers' side of the connection (``appender.DuckDBTarget``) -------------

    @property
    def generation(self) -> int:
        """Grows with every reopen: a writer's cursor of an older one is closed."""
        return self._generation

    @property
    def invalid(self) -> bool:
        """The database instance is invalid (a reopen is due or running)."""
        return self._broken is not None

    def new_cursor(self) -> duckdb.DuckDBPyConnection:
        """A cursor of the writer's own on the current connection (readers
        use ``cursor()``); make and use it under ``writing``."""
        return self._con.cursor()

    @contextlib.contextmanager
    def writing(self) -> Iterator[None]:
        """Hold while a writer uses its cursor: a reopen waits for it.
        ``Unavailable`` (nothing was stored) while the instance is invalid or
        being reopened."""
        if self._broken is not None:
            raise Unavailable(NOTHING_STORED)
        with self._gate.use(NOTHING_STORED):
            yield

    def notice(self, exc: BaseException) -> str | None:
        """Look at a DuckDB error for news of an invalidated database; start
        reopening it if so. Returns ``fatal_kind(exc)``."""
        kind = fatal_kind(exc)
        if kind is not None:
            self._invalidated(exc)
        return kind

    def _unavailable_reason(self) -> str:
        return "the database is being reopened after a storage failure (disk full?); retry later"

    def values_layout(self, tenant: str, subscription_id: str) -> ValuesLayout | None:
        return self.memory.layouts.get(tenant, subscription_id)

    def rejected(self, tenant: str | None, limit: int, offset: int) -> list[dict[str, Any]]:
        where, params = ("", []) if tenant is None else ("WHERE tenant = ? ", [tenant])
        rows = (
            self.cursor()
            .execute(
                f"SELECT {rejected_store.COLUMNS} FROM rejected_notifications {where}ORDER BY id DESC LIMIT ? OFFSET ?",
                [*params, limit, offset],
            )
            .fetchall()
        )
        return [rejected_store.rejected_row(*row) for row in rows]

    def rejected_page(
        self, tenant: str | None, limit: int, offset: int, max_bytes: int
    ) -> tuple[list[dict[str, Any]], int | None]:
        """``rejected`` paged by size too: (rows, next offset or None)."""
        cur = self.cursor()
        return rejected_store.page(
            lambda sql, params: cur.execute(sql, params).fetchall(),
            rejected_store.DUCKDB,
            tenant,
            limit,
            offset,
            max_bytes,
            rejected_store.rejected_row,
        )

    def _health_problem(self) -> str | None:
        if self._broken is not None:
            return "database invalidated by a storage failure, reopening: " + self._broken
        return None

    _is_storage_error = staticmethod(is_storage_error)

    def _rows(self, sql: str, params: Sequence = ()) -> list[tuple]:
        with self.reading():
            return self.cursor().execute(sql, list(params)).fetchall()

    @contextlib.contextmanager
    def retention_session(self) -> Iterator[DuckDBSession]:
        """A cursor of its own; batches hold the compactor's lock."""
        cur = self._con.cursor()
        try:
            yield DuckDBSession(self, cur)
        finally:
            cur.close()

    # -- lifecycle: invalidation and reopen ------------------------------------

    def _invalidated(self, exc: BaseException) -> None:
        """Mark the instance unusable and make sure one thread reopens it."""
        reason = first_line(exc)
        with self._lifecycle:
            if self._broken is None:
                log.error("DuckDB invalidated %s; reopening it in the background: %s", self.path, exc)
                self._broken = reason
            if self._reopening or self._stop_reopen.is_set():
                return
            self._reopening = True
            self._reopener = threading.Thread(target=self._reopen_loop, name="tsdb-reopen", daemon=True)
            self._reopener.start()

    def _reopen_loop(self) -> None:
        """Try to reopen, doubling the wait after each failure, until the
        store is healthy again (or closed)."""
        delay, max_delay = self._reopen_delays
        while not self._stop_reopen.wait(delay):
            try:
                self._reopen()
            except Exception as exc:
                log.warning("reopening %s failed, next try in %.1f s: %s", self.path, min(delay * 2, max_delay), exc)
                delay = min(delay * 2, max_delay)
                continue
            with self._lifecycle:
                if self._broken is None:  # not invalidated again meanwhile
                    self._reopening = False
                    return
            delay = self._reopen_delays[0]
        with self._lifecycle:
            self._reopening = False

    def _reopen(self) -> None:
        """Close every connection to the invalid instance (DuckDB hands out the
        same instance while one is open), open the file again (which replays
        the WAL) and rebuild what memory holds from it.

        The in-memory tails, partials and latest instances are dropped (they
        reload on demand); the series catalog, ids, layouts and latest
        locations are read back from the file, so memory matches exactly
        what is durable.
        """
        with self._gate.alone():
            if self._closed:
                return
            self._compactor.stop()
            with contextlib.suppress(duckdb.Error):
                self._con.close()
            con = connect(self.path, checkpoint_bytes=self._checkpoint_bytes)
            try:
                migrate_duckdb(con)
                self._load_state(con)
            except BaseException:
                con.close()
                raise
            self._con = con
            self._generation += 1
            self._querier = None
            self._compactor = Compactor(con, *self._compact_args, on_error=self.notice)
            self._compactor.start()
            self.reopens += 1
            with self._lifecycle:
                self._broken = None
        log.warning("reopened %s after a storage failure", self.path)

    # -- maintenance ----------------------------------------------------------

    def compact(self, full: bool = True) -> str:
        """Move hot rows into the sorted table now (and rewrite it if ``full``)."""
        with self.reading():
            try:
                self._compactor.run_once(full=full)
            except duckdb.Error as exc:
                if self.notice(exc) is not None:
                    raise Unavailable(self._unavailable_reason()) from None
                raise
        return "compacted"

    def backup(self, path: str) -> BackupReport:
        """A consistent copy of the store in the new file ``path``, with
        everything acknowledged before the call, read back and checked
        (``backup``). One at a time; readers and writers go on meanwhile."""
        if not self._backing_up.acquire(blocking=False):
            raise BackupRefused("a backup of this store is being taken; wait for it to finish")
        try:
            self.sync()  # everything acknowledged so far is applied: the copy holds it
            with self.reading():
                cur = self._con.cursor()
                try:
                    return take_backup(cur, Path(path))
                finally:
                    cur.close()
        finally:
            self._backing_up.release()

    def rewrite_rollups(self, statements: Sequence[tuple[str, list]]) -> list[tuple]:
        """One transaction on a cursor of its own, under the compactor's lock
        (as deletes and merges of rollups are)."""
        with self.reading(), self.compactor_lock():
            cur = self._con.cursor()
            try:
                cur.execute("BEGIN")
                rows: list[tuple] = []
                for sql, params in statements:
                    rows = cur.execute(sql, params).fetchall()
                cur.execute("COMMIT")
                return rows
            except BaseException:
                with contextlib.suppress(duckdb.Error):
                    cur.execute("ROLLBACK")
                raise
            finally:
                cur.close()

    def compactor_lock(self) -> contextlib.AbstractContextManager[Any]:
        """Hold while deleting rows (deletes, retention): the compactor must
        not move or rewrite them meanwhile (its copy could resurrect them)."""
        return self._compactor.holding()

    def sizes(self) -> tuple[int, int, int]:
        # fetchall, not fetchone: an unread result keeps this thread's cursor in
        # an open transaction, and a later UPDATE or DELETE committed elsewhere
        # (retention, in the background) then makes the CHECKPOINT at close fail.
        [(rows, nbytes)] = (
            self.cursor()
            .execute(
                "SELECT count(*), coalesce(sum(octet_length(body) + strlen(headers)), 0) FROM rejected_notifications"
            )
            .fetchall()
        )
        return file_bytes(self.path) + file_bytes(self.path + ".wal"), int(rows), int(nbytes)

    def close(self) -> None:
        if self._closed:
            return
        self.stop_retention()
        if self._logged is not None:
            self._logged.close()  # everything acknowledged is applied first
        self._stop_reopen.set()
        reopener = self._reopener
        if reopener is not None and reopener.is_alive():
            reopener.join()
        self._compactor.stop()
        self._committer.close()
        self._closed = True
        try:
            if self._broken is None:
                self._con.execute("CHECKPOINT")
        except duckdb.Error as exc:  # the WAL keeps everything; the next open replays it
            log.warning("checkpoint on close failed: %s", exc)
        finally:
            with contextlib.suppress(duckdb.Error):
                self._con.close()
