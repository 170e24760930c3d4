"""The embedded DuckDB backend: one file, one writer, many readers.

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
import os
import threading
from collections.abc import Iterator, Sequence
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import duckdb
import pyarrow as pa

from tsdb_service.core.config import WAL_CHECKPOINT_BYTES
from tsdb_service.core.errors import Unavailable
from tsdb_service.core.model import EntitySample, RejectedNotification
from tsdb_service.core.query import TimeRange
from tsdb_service.parse import ValuesLayout
from tsdb_service.storage import rejected as rejected_store
from tsdb_service.storage.common import (
    LD_TIME_COLUMNS,
    LOAD_LAYOUTS_SQL,
    REJECTED_INSERT_COLUMNS,
    SAMPLE_COLUMNS,
    CommittingStore,
    StagingAppender,
    first_line,
    layout_values,
    layouts_from_rows,
    naive_timestamps,
    rejected_values,
    to_micros,
    upsert_layout_sql,
    without_dropped,
)
from tsdb_service.storage.duckdb.dialect import DuckDBDialect
from tsdb_service.storage.duckdb.latest_geo import LATEST_GEO_SQL, LatestGeo
from tsdb_service.storage.duckdb.querier import DuckDBQuerier
from tsdb_service.storage.duckdb.retention import DuckDBSession
from tsdb_service.storage.duckdb.tail_cache import TailCache
from tsdb_service.storage.ld_ingest import (
    LATEST_INSTANCE_SQL,
    LatestInstances,
    drop_renotified,
    latest_keys,
    publish_staged,
    with_deletions,
)
from tsdb_service.storage.migrations import applied_versions, load_migrations, split_statements
from tsdb_service.storage.partials import HourlyPartials
from tsdb_service.storage.rejected import RejectedLimits
from tsdb_service.storage.sql.dialect import quote_ident
from tsdb_service.storage.sql.writes import delete_statements, instance_statements
from tsdb_service.write.committer import GroupCommitter
from tsdb_service.write.ops import DeleteInstance, DeleteSamples, PutLayout, ReplaceInstance

log = logging.getLogger(__name__)

# Time columns travel as epoch microseconds (exact, and cheap to convert).
TIME_COLUMNS = frozenset({"t", *LD_TIME_COLUMNS})
_ARROW_TYPES = {
    "rid": pa.int64(),
    "iid": pa.int64(),
    "sid": pa.int32(),
    "kind": pa.uint8(),
    "num": pa.float64(),
    "lon": pa.float64(),
    "lat": pa.float64(),
    "min_lon": pa.float64(),
    "min_lat": pa.float64(),
    "max_lon": pa.float64(),
    "max_lat": pa.float64(),
}
# The shared columns plus the instance id, which this store allocates.
SAMPLE_SCHEMA = pa.schema(
    [
        (name, pa.timestamp("us") if name in TIME_COLUMNS else _ARROW_TYPES.get(name, pa.string()))
        for name in (*SAMPLE_COLUMNS, "iid")
    ]
)

SeriesKey = tuple[str, str, str, str, str]  # tenant, service path, id, type, attr

REQUIRED = frozenset({"rid", "sid", "t", "kind", "iid"})


INSERT_SERIES = (
    "INSERT INTO series BY NAME SELECT unnest($1::INTEGER[]) AS sid, unnest($2::VARCHAR[]) AS tenant, "
    "unnest($3::VARCHAR[]) AS service_path, unnest($4::VARCHAR[]) AS entity_id, "
    "unnest($5::VARCHAR[]) AS entity_type, unnest($6::VARCHAR[]) AS attr, unnest($7::VARCHAR[]) AS dataset_id"
)
_DIALECT = DuckDBDialect()
_SAMPLE_TABLES = ("samples", "samples_hot")
# Above this many rows a batch goes through Arrow (bulk loads, copies).
ARROW_MIN_ROWS = 2048
# Appenders a writer keeps, one per set of columns its groups filled (about
# 55 KB each): a few shapes cover ordinary traffic.
MAX_ROW_APPENDERS = 16
# After the database is invalidated: first reopen attempt, then doubling to at most.
REOPEN_DELAY_S = 0.5
REOPEN_MAX_DELAY_S = 10.0

# How DuckDB says it gave up on the database instance (duckdb.FatalException).
_INVALIDATED = "database has been invalidated"
_COMMITTED_ANYWAY = "COMMIT succeeded"
NOTHING_STORED = "the database is being reopened after a storage failure (disk full?); nothing was stored, retry later"
MAYBE_STORED = "the database failed while committing (disk full?); this write may or may not have been stored"


def fatal_kind(exc: BaseException) -> str | None:
    """What a DuckDB error says about the database instance:

    ``"refused"``: it was already invalidated, the call did nothing;
    ``"committed"``: the transaction is durable, the checkpoint after it failed
    and the instance is now invalid;
    ``"unknown"``: some other fatal error, the instance is invalid and the
    call's outcome unknown;
    None: an ordinary error, the instance is fine.

    The "invalidated" message quotes the original error (often the
    "COMMIT succeeded" one), so it is tested first.
    """
    text = str(exc)
    if _INVALIDATED in text:
        return "refused"
    if not isinstance(exc, duckdb.FatalException):
        return None
    return "committed" if _COMMITTED_ANYWAY in text else "unknown"


def is_storage_error(exc: BaseException) -> bool:
    """A failure to write the file (full disk, I/O error): the database
    refuses writes until the cause goes away."""
    text = str(exc)
    return isinstance(exc, duckdb.IOException) or "No space left" in text or "Could not write" in text


def _micros_or_none(moment: datetime | None) -> int | None:
    return None if moment is None else to_micros(moment)


def migrate_duckdb(con: duckdb.DuckDBPyConnection) -> list[int]:
    """Apply pending migrations; return the versions applied now."""
    done = applied_versions(con)
    applied = []
    for migration in load_migrations("duckdb"):
        if migration.version in done:
            continue
        con.execute("BEGIN")
        try:
            for statement in split_statements(migration.sql):
                con.execute(statement)
            con.execute(
                "INSERT INTO schema_migrations (version, name) VALUES (?, ?)",
                [migration.version, migration.name],
            )
            con.execute("COMMIT")
        except Exception:
            con.execute("ROLLBACK")
            raise
        applied.append(migration.version)
    return applied


def connect(path: str, read_only: bool = False, checkpoint_bytes: int | None = None) -> duckdb.DuckDBPyConnection:
    if path != ":memory:":
        Path(path).parent.mkdir(parents=True, exist_ok=True)
    try:
        con = duckdb.connect(path, read_only=read_only)
    except duckdb.IOException as exc:
        if "lock" in str(exc).lower():
            raise RuntimeError(
                f"{path} is open in another process. DuckDB allows one process per file: "
                "stop the other tsdb-service, or use PostgreSQL (--db postgresql://...) "
                "to run several."
            ) from exc
        raise
    if checkpoint_bytes is not None and not read_only:
        # Set on the database instance, not as a connect() option: DuckDB
        # refuses a second in-process connection to a file opened with a
        # different configuration, and a plain connect() (migrate, probes,
        # read-only checks) shares the instance and its setting instead.
        # An int, formatted: SET takes no bound parameters.
        con.execute(f"SET GLOBAL wal_autocheckpoint = '{int(checkpoint_bytes)}B'")
    return con


class Gate:
    """Many users of the database connection at once, or one reopen alone.

    Closing a DuckDB connection while another thread runs a query on one of
    its cursors is not safe, so readers and writers hold the gate while they
    use a cursor and the reopen waits for them to leave. Nobody waits to
    enter: while a reopen runs, entering raises ``Unavailable``.
    """

    def __init__(self) -> None:
        self._cond = threading.Condition()
        self._users = 0
        self._shut = False

    @contextlib.contextmanager
    def use(self, refusal: str) -> Iterator[None]:
        with self._cond:
            if self._shut:
                raise Unavailable(refusal)
            self._users += 1
        try:
            yield
        finally:
            with self._cond:
                self._users -= 1
                if self._users == 0:
                    self._cond.notify_all()

    @contextlib.contextmanager
    def alone(self) -> Iterator[None]:
        with self._cond:
            self._shut = True
            self._cond.wait_for(lambda: self._users == 0)
        try:
            yield
        finally:
            with self._cond:
                self._shut = False


class DuckDBStore(CommittingStore):
    backend = "duckdb"

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
    ):
        self.path = path
        # Rejected-store bounds (storage.rejected) and what they dropped, by reason.
        self.rejected_limits = rejected_limits or RejectedLimits()
        self.rejected_dropped = dict.fromkeys(rejected_store.REASONS, 0)
        self._checkpoint_bytes = checkpoint_bytes
        self._compact_args = (compact_rows, major_compact_runs)
        self._tail_args = (tail_series, tail_rows, tail_samples)
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
        self._generation = 0  # grows with every reopen: cursors of older ones are closed
        self._pending_series: dict[SeriesKey, int] = {}
        self._series: dict[SeriesKey, int] = {}
        self._layouts: dict[tuple[str, str], ValuesLayout] = {}
        self._next_sid = self._next_rid = self._next_rejected = 1
        # Writers allocate series ids, row ids and rejection ids under this.
        self._alloc_lock = threading.Lock()
        self._series_lock = threading.Lock()
        self.tail = TailCache(*self._tail_args)
        # Aggregate partials (storage.partials) need row ids growing in commit order: one writer.
        self.partials = HourlyPartials(agg_partials_hours if writer_threads == 1 else 0)
        self.latest_instances = LatestInstances()
        self._next_iid = 1
        self._con = connect(path, checkpoint_bytes=checkpoint_bytes)
        migrate_duckdb(self._con)
        self._load_state(self._con)
        self._compactor = Compactor(self._con, *self._compact_args, on_error=self.notice)
        self._committer = GroupCommitter(lambda: DuckDBAppender(self), threads=writer_threads)
        self._committer.start()
        self._compactor.start()
        self._closed = False
        self._querier: DuckDBQuerier | None = None

    def _load_state(self, con: duckdb.DuckDBPyConnection) -> None:
        """What the store keeps in memory, from the file: the series ids, the
        next ids to hand out (never lower than ones already handed out), the
        'values' layouts and each series' latest location."""
        series = {
            tuple(row[1:]): row[0]
            for row in con.execute(
                "SELECT sid, tenant, service_path, entity_id, entity_type, attr FROM series"
            ).fetchall()
        }
        max_rid = _tables_max(con, "rid")
        max_iid = _tables_max(con, "iid")
        max_rejected = _scalar(con, "SELECT max(id) FROM rejected_notifications") or 0
        layouts = layouts_from_rows(con.execute(LOAD_LAYOUTS_SQL).fetchall())
        latest_geo = LatestGeo(con.execute(LATEST_GEO_SQL.format(where="")).fetchall())
        with self._alloc_lock:
            self._series = series
            self._next_sid = max(self._next_sid, max(series.values(), default=0) + 1)
            self._next_rid = max(self._next_rid, max_rid + 1)
            self._next_iid = max(self._next_iid, max_iid + 1)
            self._next_rejected = max(self._next_rejected, max_rejected + 1)
        self._layouts = layouts
        self.latest_geo = latest_geo

    # -- history reads (storage.duckdb.querier) ------------------------------------

    def querier(self) -> DuckDBQuerier:
        if self._querier is None:
            self._querier = DuckDBQuerier(self)
        return self._querier

    def series_generation(self) -> int:
        """Grows whenever the writer publishes new series (after commit)."""
        return len(self._series)

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
        return self._layouts.get((tenant, subscription_id))

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
        reason = _first_line(exc)
        with self._lifecycle:
            if self._broken is None:
                log.error("DuckDB invalidated %s; reopening it in the background: %s", self.path, exc)
                self._broken = reason
            if self._reopening or self._stop_reopen.is_set():
                return
            self._reopening = True
            self._reopener = threading.Thread(target=self._reopen_loop, name="tsdb-reopen", daemon=True)
            self._reopener.start()

    def forget(self, sids) -> None:
        """Series whose stored samples were deleted or changed: every
        per-series memory (tails, hourly partials, latest NGSI-LD instance)
        lets go of them and reloads them from the database when next asked.
        Latest locations are recomputed by the callers, which know the rows."""
        self.tail.drop(sids)
        self.partials.drop(sids)
        self.latest_instances.drop(sids)

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

        The in-memory tails are dropped (they reload on demand); the series
        catalog, ids, layouts and latest locations are read back from the
        file, so memory matches exactly what is durable.
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
            self.tail = TailCache(*self._tail_args)
            self.partials = HourlyPartials(self.partials.max_hours)
            self.latest_instances = LatestInstances()
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

    def compactor_lock(self) -> contextlib.AbstractContextManager[Any]:
        """Hold while deleting rows (deletes, retention): the compactor must
        not move or rewrite them meanwhile (its copy could resurrect them)."""
        return self._compactor._lock

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
        return _file_bytes(self.path) + _file_bytes(self.path + ".wal"), int(rows), int(nbytes)

    def close(self) -> None:
        if self._closed:
            return
        self.stop_retention()
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


_first_line = first_line


def _tables_max(cur: duckdb.DuckDBPyConnection, column: str) -> int:
    """The largest ``column`` over both sample tables, each asked alone:
    DuckDB answers a base table's max from its row groups' statistics
    (reading only the row groups that can hold it), but the max over the
    ``samples_all`` view reads the whole column, and the blocks it read
    stayed in memory: about 160 MiB more RSS at start-up with 100M samples."""
    return max(
        (_scalar(cur, f"SELECT max({quote_ident(column)}) FROM {quote_ident(table)}") or 0) for table in _SAMPLE_TABLES
    )


def _scalar(cur: duckdb.DuckDBPyConnection, sql: str) -> Any:
    """The one value of an aggregate query."""
    row = cur.execute(sql).fetchone()
    return None if row is None else row[0]


class DuckDBAppender(StagingAppender):
    """Turns staged ops into columnar batches; only the writer thread uses it."""

    def __init__(self, store: DuckDBStore):
        self._store = store
        self._cur = store._con.cursor()
        self._generation = store._generation
        # DuckDB appenders on self._cur, one per set of columns a group fills
        self._row_appenders: dict[tuple[str, ...], Any] = {}
        self._reset()

    def _current_cursor(self) -> duckdb.DuckDBPyConnection:
        """This writer's cursor on the store's current connection (a reopen
        closed the one made on the previous connection)."""
        store = self._store
        if self._generation != store._generation:
            self._cur = store._con.cursor()
            self._generation = store._generation
            self._row_appenders = {}
        return self._cur

    def _reset(self) -> None:
        self._cols: dict[str, list] = {name: [] for name in SAMPLE_SCHEMA.names}
        self._new_series: dict[SeriesKey, int] = {}
        self._new_datasets: dict[SeriesKey, str] = {}  # new series of non-default datasetIds
        self._latest: dict[SeriesKey, tuple | None] = {}  # this transaction's latest instance keys
        self._rejected: list[tuple] = []
        self._layouts: list[PutLayout] = []
        self._deletes: list[tuple[DeleteSamples, int]] = []
        self._instance_ops: list[DeleteInstance | ReplaceInstance] = []

    def _stage_delete(self, op: DeleteSamples) -> None:
        # Rows allocated after this op was staged (by any writer) survive it.
        self._deletes.append((op, self._store._next_rid - 1))

    def _sid(self, key: SeriesKey) -> int:
        """The series id for ``key``; caller holds the store's allocation lock.

        Several writers share one id space: an id not yet committed is kept
        in ``_pending_series`` so every writer uses the same id for a key,
        and each writer that uses it inserts the series row itself (OR
        IGNORE), so no sample can outlive a failed series insert.
        """
        store = self._store
        sid = store._series.get(key)
        if sid is not None:
            return sid
        sid = self._new_series.get(key)
        if sid is None:
            sid = store._pending_series.get(key)
            if sid is None:
                sid = store._pending_series[key] = store._next_sid
                store._next_sid += 1
            self._new_series[key] = sid
        return sid

    def _stage_samples(self, entities: Sequence[EntitySample], dedup: bool) -> None:
        store = self._store
        entities = with_deletions(entities, self._entity_attrs)
        with store._alloc_lock:
            entities = self._without_renotified(entities, dedup)
            self._stage_locked(entities)

    def _entity_attrs(self, entity: EntitySample) -> list[tuple[str, str | None]]:
        """Stored attributes (name, datasetId) of a deleted entity."""
        return self._cur.execute(
            "SELECT attr, dataset_id FROM series WHERE tenant = ? AND service_path = ? AND entity_id = ? "
            "AND entity_type = ? ORDER BY attr",
            [entity.tenant, entity.service_path, entity.entity_id, entity.entity_type],
        ).fetchall()

    def _without_renotified(self, entities: Sequence[EntitySample], dedup: bool) -> list[EntitySample]:
        """Drop NGSI-LD instances equal to their series' latest stored one
        (``dedup``; else only note them as the latest)."""
        if not any(a.observed_at is not None for e in entities for a in e.attrs):
            return list(entities)
        series = self._store._series
        items = []
        for e in entities:
            prefix = (e.tenant, e.service_path, e.entity_id, e.entity_type)
            for a in e.attrs:
                key = (*prefix, a.name)
                items.append((key, series.get(key) or self._new_series.get(key), a, dedup))
        return without_dropped(
            entities, drop_renotified(items, self._store.latest_instances, self._latest, self._latest_of)
        )

    def _latest_of(self, sids: list[int]) -> dict:
        return latest_keys(
            self._cur.execute(
                LATEST_INSTANCE_SQL.format(table="samples_all", sids="sid IN (SELECT unnest(?::INTEGER[]))"), [sids]
            ).fetchall()
        )

    def _stage_locked(self, entities: Sequence[EntitySample]) -> None:
        c = self._cols
        rid_, sid_, t_, kind_, atype_, num_, txt_, js_, md_ = (
            c["rid"],
            c["sid"],
            c["t"],
            c["kind"],
            c["atype"],
            c["num"],
            c["txt"],
            c["js"],
            c["md"],
        )
        geo_, lon_, lat_ = c["geo"], c["lon"], c["lat"]
        mnlon, mnlat, mxlon, mxlat = c["min_lon"], c["min_lat"], c["max_lon"], c["max_lat"]
        iid_, obs_, cre_, mod_, del_ = c["iid"], c["observed_at"], c["created_at"], c["modified_at"], c["deleted_at"]
        store = self._store
        for entity in entities:
            rid = store._next_rid
            store._next_rid += 1
            micros = to_micros(entity.time_index)
            prefix = (entity.tenant, entity.service_path, entity.entity_id, entity.entity_type)
            for attr in entity.attrs:
                key = (*prefix, attr.name)
                rid_.append(rid)
                sid_.append(self._sid(key))
                iid_.append(store._next_iid)
                store._next_iid += 1
                t_.append(micros)
                kind_.append(int(attr.kind))
                atype_.append(attr.ngsi_type)
                num_.append(attr.num)
                txt_.append(attr.txt)
                js_.append(attr.js)
                md_.append(attr.md)
                if (
                    attr.observed_at is None
                    and attr.created_at is None
                    and attr.modified_at is None
                    and attr.deleted_at is None
                    and attr.dataset_id is None
                ):
                    obs_.append(None)
                    cre_.append(None)
                    mod_.append(None)
                    del_.append(None)
                else:
                    obs_.append(_micros_or_none(attr.observed_at))
                    cre_.append(_micros_or_none(attr.created_at))
                    mod_.append(_micros_or_none(attr.modified_at))
                    del_.append(_micros_or_none(attr.deleted_at))
                    if attr.dataset_id is not None and key in self._new_series:
                        self._new_datasets[key] = attr.dataset_id
                g = attr.geo
                if g is None:
                    geo_.append(None)
                    lon_.append(None)
                    lat_.append(None)
                    mnlon.append(None)
                    mnlat.append(None)
                    mxlon.append(None)
                    mxlat.append(None)
                else:
                    geo_.append(g.geojson)
                    lon_.append(g.lon)
                    lat_.append(g.lat)
                    mnlon.append(g.min_lon)
                    mnlat.append(g.min_lat)
                    mxlon.append(g.max_lon)
                    mxlat.append(g.max_lat)

    def _stage_rejected(self, r: RejectedNotification) -> None:
        store = self._store
        with store._alloc_lock:
            rejected_id = store._next_rejected
            store._next_rejected += 1
        self._rejected.append((rejected_id, *rejected_values(r)))

    def commit(self) -> None:
        """Commit the staged ops, or raise ``Unavailable`` saying whether
        anything may have been stored when the database instance is (or has
        just become) invalid: the group committer must not retry then.

        A commit whose automatic checkpoint failed is durable: it is
        published and acknowledged like any other, and the store reopens.
        """
        store = self._store
        if store._broken is not None:
            raise Unavailable(NOTHING_STORED)
        with store._gate.use(NOTHING_STORED):
            try:
                self._commit(self._current_cursor())
            except duckdb.Error as exc:
                store._note_write(exc)
                kind = store.notice(exc)
                if kind == "refused":
                    raise Unavailable(NOTHING_STORED) from exc
                if kind is not None:
                    raise Unavailable(MAYBE_STORED) from exc
                raise
        store._note_write(None)

    def _durable(self, cur: duckdb.DuckDBPyConnection, sql: str, params=None) -> None:
        """Execute a statement that commits (autocommit, or COMMIT itself).
        "COMMIT succeeded ... but the autocheckpoint failed" means it did:
        carry on as committed (the store starts reopening; the next
        statement will be refused)."""
        try:
            cur.execute(sql, params)
        except duckdb.Error as exc:
            if not self._committed_anyway(exc):
                raise

    def _committed_anyway(self, exc: duckdb.Error) -> bool:
        """True when ``exc`` says the commit landed and only its checkpoint
        failed: logged, and the store told to reopen."""
        if fatal_kind(exc) != "committed":
            return False
        log.warning("commit is durable but its checkpoint failed: %s", _first_line(exc))
        self._store.notice(exc)
        return True

    def _commit(self, cur: duckdb.DuckDBPyConnection) -> None:
        """Make the staged ops durable with as few database calls as possible.

        Under load the event loop holds the GIL, and every return from
        DuckDB into Python waits for it. A small batch is therefore appended
        and flushed in autocommit mode: two calls, one transaction. Big
        batches (bulk loads) go through Arrow instead, where the per-row
        conversion cost matters more than the GIL. New series
        rows are committed first; if the samples then fail, an unused series
        row is harmless.
        """
        if self._new_series:
            store = self._store
            # Series rows are written one writer at a time, each skipping the
            # keys another writer has committed meanwhile: a plain INSERT that
            # cannot conflict (OR IGNORE is several times slower in DuckDB).
            with store._series_lock:
                keys = [k for k in self._new_series if k not in store._series]
                if keys:
                    self._durable(
                        cur,
                        INSERT_SERIES,
                        [
                            [self._new_series[k] for k in keys],
                            *([k[i] for k in keys] for i in range(5)),
                            [self._new_datasets.get(k) for k in keys],
                        ],
                    )
                with store._alloc_lock:
                    store._series.update(self._new_series)
                    for key in self._new_series:
                        store._pending_series.pop(key, None)
            self._new_series = {}
        if self._cols["rid"]:
            if len(self._cols["rid"]) <= ARROW_MIN_ROWS:
                # Only columns that carry a value: converting the all-NULL
                # ones (geometry, metadata...) would hold the GIL for nothing.
                names = tuple(
                    n for n in SAMPLE_SCHEMA.names if n in REQUIRED or any(v is not None for v in self._cols[n])
                )
                self._append_rows(cur, names)
            else:
                self._insert_arrow(cur)
            self._store.tail.publish(self._cols)
            self._store.latest_geo.publish(self._cols)
            self._store.partials.publish(self._cols)
        if self._rejected or self._layouts or self._deletes or self._instance_ops:
            # A delete must not race the compactor moving or rewriting the
            # same rows (its copy could resurrect them): hold its lock.
            changes = self._deletes or self._instance_ops
            guard = self._store.compactor_lock() if changes else contextlib.nullcontext()
            with guard:
                self._commit_other(cur)
        publish_staged(self._store.latest_instances, self._latest, self._store._series.get)
        self._publish()

    def _append_rows(self, cur: duckdb.DuckDBPyConnection, names: tuple[str, ...]) -> None:
        """The staged rows of ``names`` through a DuckDB appender, flushed in
        autocommit mode: one statement, its own transaction, one WAL fsync,
        as durable as an INSERT. A third cheaper in CPU than the INSERT ...
        SELECT unnest($1..$n) it replaces (binding and planning that
        statement was most of a small group's cost), at 8 to 100
        notifications a group (``benchmarks/README.md``).

        An appender keeps the rows buffered before a failure, and a later
        flush would store them: after any error its buffer is cleared and
        it is dropped, so a retry starts from nothing."""
        appender = self._row_appenders.get(names)
        if appender is None:
            if len(self._row_appenders) >= MAX_ROW_APPENDERS:  # payloads of many shapes: the oldest goes
                del self._row_appenders[next(iter(self._row_appenders))]
            appender = self._row_appenders[names] = cur.appender("samples_hot", columns=list(names))
        cols = self._cols
        try:
            appender.append_rows(
                zip(*(naive_timestamps(cols[n]) if n in TIME_COLUMNS else cols[n] for n in names), strict=True)
            )
            appender.flush()
        except BaseException as exc:  # a value it cannot convert raises a plain Python error
            del self._row_appenders[names]
            with contextlib.suppress(duckdb.Error):
                appender.clear()
            if not (isinstance(exc, duckdb.Error) and self._committed_anyway(exc)):
                raise

    def _insert_arrow(self, cur: duckdb.DuckDBPyConnection) -> None:
        cols = self._cols
        arrays = [
            pa.array(cols[f.name], pa.int64()).cast(f.type)
            if f.name in TIME_COLUMNS
            else pa.array(cols[f.name], f.type)
            for f in SAMPLE_SCHEMA
        ]
        cur.register("_batch", pa.Table.from_arrays(arrays, schema=SAMPLE_SCHEMA))
        try:
            self._durable(cur, "INSERT INTO samples_hot BY NAME SELECT * FROM _batch")
        finally:
            with contextlib.suppress(duckdb.Error):  # fails on an invalid instance
                cur.unregister("_batch")

    def _commit_other(self, cur: duckdb.DuckDBPyConnection) -> None:
        cur.execute("BEGIN")
        for row in self._rejected:
            cur.execute(
                f"INSERT INTO rejected_notifications (id, {REJECTED_INSERT_COLUMNS}) "
                "VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?)",
                list(row),
            )
        dropped = None
        if self._rejected:
            dropped = rejected_store.prune(
                lambda sql, params: cur.execute(sql, params).fetchall(),
                rejected_store.DUCKDB,
                [row[1] for row in self._rejected],
                self._store.rejected_limits,
            )
        for put in self._layouts:
            cur.execute(upsert_layout_sql("?"), layout_values(put, datetime.now(UTC)))
        for op, upto_rid in self._deletes:
            for sql, params in delete_statements(
                _DIALECT, _SAMPLE_TABLES, op.sids, TimeRange(op.start, op.end), upto_rid
            ):
                cur.execute(sql, params)
        for instance_op in self._instance_ops:
            for sql, params in instance_statements(_DIALECT, _SAMPLE_TABLES, instance_op):
                cur.execute(sql, params)
        self._durable(cur, "COMMIT")
        if dropped:
            rejected_store.count_dropped(self._store.rejected_dropped, dropped)
        store = self._store
        for op, upto_rid in self._deletes:
            store.forget(op.sids)
            if store._broken is None:  # else the reopen rebuilds every location
                store.latest_geo.recompute(op.sids, upto_rid, self._latest_geo_of)
        for instance_op in self._instance_ops:
            store.forget([instance_op.sid])
            if store._broken is None:
                store.latest_geo.recompute([instance_op.sid], store._next_rid, self._latest_geo_of)

    def _latest_geo_of(self, sids: list[int]) -> list[tuple]:
        return self._cur.execute(
            LATEST_GEO_SQL.format(where="AND sid IN (SELECT unnest(?::INTEGER[]))"), [sids]
        ).fetchall()

    def _publish(self) -> None:
        """Expose only what is durable."""
        self._store._series.update(self._new_series)
        for put in self._layouts:
            self._store._layouts[(put.tenant, put.subscription_id)] = put.layout
        self._reset()

    def rollback(self) -> None:
        # Ids staged for new series stay reserved in _pending_series: the
        # next writer to see those keys inserts their rows.
        try:
            if self._store._broken is None and self._generation == self._store._generation:
                with self._store._gate.use(NOTHING_STORED):
                    self._cur.execute("ROLLBACK")
        except (duckdb.Error, Unavailable):
            pass  # no transaction was open, or the connection is being replaced
        self._reset()

    def close(self) -> None:
        self._row_appenders = {}
        with contextlib.suppress(duckdb.Error):
            self._cur.close()


class Compactor:
    """Keeps the sorted table sorted, off the acknowledgement path.

    Moving hot rows is one transaction (insert sorted, delete moved), so a
    reader sees each sample exactly once. Only this thread touches
    ``samples``; the writer only appends to ``samples_hot``; the two never
    conflict.
    """

    def __init__(
        self, con: duckdb.DuckDBPyConnection, compact_rows: int, major_runs: int, interval: float = 2.0, on_error=None
    ):
        self._con = con
        self._on_error = on_error  # told about each failure (the store looks for invalidation)
        self._compact_rows = compact_rows
        self._major_runs = major_runs
        self._interval = interval
        self._runs = 0
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, name="tsdb-compactor", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join()

    def _loop(self) -> None:
        cur = self._con.cursor()
        try:
            while not self._stop.wait(self._interval):
                try:
                    hot = _scalar(cur, "SELECT count(*) FROM samples_hot")
                    if hot >= self._compact_rows:
                        self._move(cur)
                        if self._runs >= self._major_runs:
                            self._rewrite(cur)
                except Exception as exc:  # keep serving; compaction is an optimisation
                    _rollback_quietly(cur)
                    if self._on_error is not None and self._on_error(exc) is not None:
                        log.warning("compaction stopped, the database is invalid: %s", _first_line(exc))
                        return  # the store's reopen starts a new compactor
                    log.exception("compaction failed; will retry")
        finally:
            cur.close()

    def run_once(self, full: bool) -> None:
        cur = self._con.cursor()
        try:
            self._move(cur)
            if full:
                self._rewrite(cur)
        finally:
            cur.close()

    def _move(self, cur: duckdb.DuckDBPyConnection) -> None:
        with self._lock:
            cur.execute("BEGIN")
            try:
                upto = _scalar(cur, "SELECT max(rid) FROM samples_hot")
                if upto is None:
                    cur.execute("COMMIT")
                    return
                cur.execute(
                    "INSERT INTO samples SELECT * FROM samples_hot WHERE rid <= ? ORDER BY sid, t, rid",
                    [upto],
                )
                cur.execute("DELETE FROM samples_hot WHERE rid <= ?", [upto])
                cur.execute("COMMIT")
            except Exception:
                _rollback_quietly(cur)
                raise
            self._runs += 1

    def _rewrite(self, cur: duckdb.DuckDBPyConnection) -> None:
        with self._lock:
            cur.execute("BEGIN")
            try:
                cur.execute("CREATE TABLE samples_sorted AS SELECT * FROM samples ORDER BY sid, t, rid")
                cur.execute("DROP TABLE samples")
                cur.execute("ALTER TABLE samples_sorted RENAME TO samples")
                cur.execute("COMMIT")
            except Exception:
                _rollback_quietly(cur)
                raise
            self._runs = 0


def _rollback_quietly(cur: duckdb.DuckDBPyConnection) -> None:
    with contextlib.suppress(duckdb.Error):
        cur.execute("ROLLBACK")


def _file_bytes(path: str) -> int:
    try:
        return os.stat(path).st_size
    except FileNotFoundError:
        return 0
