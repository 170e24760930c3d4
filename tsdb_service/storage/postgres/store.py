"""The PostgreSQL backend, for several service processes on one database.

The write path is the DuckDB one: a group committer per process, one
transaction per group, samples sent with binary ``COPY``. A group of plain
samples of known series is a single autocommit ``COPY`` (two round trips);
others open a transaction whose first statements share one pipeline round
trip. Row ids come from blocks reserved from the sequence. Series ids are shared
through the ``series`` table (insert-if-absent, in key order so concurrent
writers cannot deadlock). Reads use a connection pool.

A failed write is answered "nothing was stored" only when the transaction
certainly did not commit: an error before COMMIT, or one the server raised
for the COMMIT itself on a live connection (the server rolled back). When the
connection breaks during COMMIT (or once an autocommit COPY's end was sent)
nobody can say, and the answer says so.
``/health`` fails while the database refuses writes for lack of space or an
I/O error, until a write succeeds again.
"""

from __future__ import annotations

import contextlib
import logging
import threading
import time
from collections.abc import Callable, Sequence
from datetime import UTC, datetime
from typing import Any

import psycopg
from psycopg_pool import ConnectionPool

from tsdb_service.core.errors import Unavailable
from tsdb_service.core.model import EntitySample, RejectedNotification
from tsdb_service.core.query import TimeRange
from tsdb_service.parse import ValuesLayout
from tsdb_service.read.off_loop import check_database_allowed
from tsdb_service.storage import rejected as rejected_store
from tsdb_service.storage.common import (
    GEO_COLUMNS,
    LD_TIME_COLUMNS,
    LOAD_LAYOUTS_SQL,
    REJECTED_INSERT_COLUMNS,
    SAMPLE_COLUMNS,
    CommittingStore,
    StagingAppender,
    delivery_statements,
    layout_values,
    layouts_from_rows,
    naive_utc,
    rejected_values,
    upsert_layout_sql,
    without_dropped,
)
from tsdb_service.storage.ld_ingest import LatestInstances, drop_renotified, latest_keys, publish_staged, with_deletions
from tsdb_service.storage.migrations import applied_versions, load_migrations
from tsdb_service.storage.postgres.dialect import PostgresDialect, int_array
from tsdb_service.storage.postgres.extents import ExtentLedger
from tsdb_service.storage.postgres.querier import PostgresQuerier
from tsdb_service.storage.postgres.retention import PostgresSession, postgres_session
from tsdb_service.storage.postgres.untimed import UntimedLedger
from tsdb_service.storage.rejected import RejectedLimits
from tsdb_service.storage.sql.writes import delete_statements, instance_statements
from tsdb_service.write.committer import GroupCommitter
from tsdb_service.write.ops import DeleteInstance, DeleteSamples, Delivery, PutLayout, ReplaceInstance

log = logging.getLogger(__name__)

# SAMPLE_COLUMNS (common): iid is the column default's (a sequence).
_NO_GEO = (None,) * len(GEO_COLUMNS)
# Binary: half the client CPU of text rows and ~15 % less of the server's
# (no number/timestamp parsing); the types are the columns' (migrations).
_COPY_SAMPLES = f"COPY samples ({', '.join(SAMPLE_COLUMNS)}) FROM STDIN (FORMAT BINARY)"
_GEO_TYPES = ("text", *("float8",) * (len(GEO_COLUMNS) - 1))
_SAMPLE_TYPES = (
    ("int8", "int4", "timestamp", "int2", "text", "float8", "text", "text")
    + _GEO_TYPES
    + ("text",)
    + ("timestamp",) * len(LD_TIME_COLUMNS)
)
_DIALECT = PostgresDialect()
SeriesKey = tuple[str, str, str, str, str]
_MIGRATION_LOCK = 0x7473_6462  # "tsdb": serialises migrations across processes
WRITER_APPLICATION_NAME = "tsdb-service writer"
# SQLSTATE classes that mean the server cannot write: insufficient resources
# (53100 disk_full...) and system errors (58030 io_error...).
_STORAGE_CLASSES = ("53", "58")
# 'values' layouts older than this are read again before use: another
# replica may have registered the subscription again with other attributes.
LAYOUTS_MAX_AGE = 10.0
MAYBE_STORED = "the connection to the database broke during the commit; this write may or may not have been stored"


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
            conn.execute(
                "INSERT INTO schema_migrations (version, name) VALUES (%s, %s)",
                [migration.version, migration.name],
            )
            applied.append(migration.version)
    return applied


def _naive(moment: datetime | None) -> datetime | None:
    return None if moment is None else naive_utc(moment)


class PostgresStore(CommittingStore):
    backend = "postgresql"

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
        self._series: dict[SeriesKey, int] = {}
        self.row_ids = RowIds()
        self.latest_instances = LatestInstances()
        self.geo_extents = ExtentLedger()  # .extents: where each series has ever been
        self.untimed = UntimedLedger(self._series)  # series listed as holding instances without observedAt
        self._layouts: dict[tuple[str, str], ValuesLayout] = {}
        self._layouts_lock = threading.Lock()
        self._layouts_read_at = float("-inf")
        self._load_layouts()
        self._committer = GroupCommitter(lambda: PostgresAppender(self), name="tsdb-pg-writer", threads=writer_threads)
        self._committer.start()
        self._closed = False
        self._querier = PostgresQuerier(self, agg_partials_hours)

    def querier(self) -> PostgresQuerier:
        return self._querier

    def series_created(self) -> int:
        """Series this process's writers created and committed (grows only)."""
        return len(self._series)

    def connection(self) -> contextlib.AbstractContextManager[psycopg.Connection]:
        """A pooled connection (context manager) for reads."""
        if self._closed:
            raise Unavailable("the store is closed")
        return self.pool.connection()

    def _load_layouts(self, max_age: float = 0.0) -> None:
        """Read every registered layout from the database (at open, and
        off the event loop: see ``values_layout``), unless another thread
        read them less than ``max_age`` seconds ago. Under the lock, so a
        layout this process commits meanwhile (``layouts_committed``) is
        never replaced by an older read."""
        check_database_allowed()
        with self._layouts_lock:
            started = time.monotonic()
            if started - self._layouts_read_at <= max_age:
                return
            with self.pool.connection() as conn:
                rows = conn.execute(LOAD_LAYOUTS_SQL).fetchall()
            self._layouts = layouts_from_rows(rows)
            self._layouts_read_at = started

    def layouts_committed(self, puts: Sequence[PutLayout]) -> None:
        """This process's layouts, current as soon as they are committed."""
        if puts:
            with self._layouts_lock:
                for put in puts:
                    self._layouts[(put.tenant, put.subscription_id)] = put.layout

    def values_layout(self, tenant: str, subscription_id: str) -> ValuesLayout | None:
        """From memory. Another replica may have registered the subscription
        (or registered it again with other attributes), so a miss, or layouts
        read over ``LAYOUTS_MAX_AGE`` ago, read them again first: a database
        call, which on the event loop raises ``NeedsDatabase`` instead, and
        ``Store.read`` re-runs the parse in the threadpool."""
        key = (tenant, subscription_id)
        layout = self._layouts.get(key)
        if layout is None:
            self._load_layouts()
            layout = self._layouts.get(key)
        elif time.monotonic() - self._layouts_read_at > LAYOUTS_MAX_AGE:
            self._load_layouts(LAYOUTS_MAX_AGE)
            layout = self._layouts.get(key)
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
        """Nothing to do: samples stay where they were written, and the
        (sid, t) index already serves every read in order."""
        return "nothing to compact: PostgreSQL keeps samples in place (only DuckDB files are compacted)"

    def retention_session(self) -> contextlib.AbstractContextManager[PostgresSession | None]:
        """A connection of its own holding the cluster-wide pass lock."""
        return postgres_session(self.url, lambda sids: self.latest_instances.drop(sids))

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
        self._committer.close()
        self._closed = True
        self._querier.close()
        self.pool.close()


def _fetch_all(cur: psycopg.Cursor):
    def execute(sql: str, params: list) -> list[tuple]:
        cur.execute(sql, params)
        return cur.fetchall()

    return execute


def _reserve(cur: psycopg.Cursor) -> Callable[[int], list[int]]:
    def reserve(n: int) -> list[int]:
        cur.execute("SELECT nextval('sample_rid_seq') FROM generate_series(1, %s)", [n])
        return sorted(row[0] for row in cur.fetchall())

    return reserve


class RowIds:
    """Row ids (``rid``, one per entity sample) handed out in order from
    blocks reserved from ``sample_rid_seq``: one ``nextval`` round trip per
    ``block`` ids instead of one per group. Ids are unique across replicas
    (the sequence) and, within this process, increase in the order groups
    take them, as when each group called ``nextval`` itself (reads order
    samples of one instant by rid). Unused ids of a block are gaps, which a
    sequence has anyway."""

    def __init__(self, block: int = 1024):
        self.block = block
        self._free: list[int] = []
        self._lock = threading.Lock()

    def take(self, n: int, reserve: Callable[[int], list[int]]) -> list[int]:
        """``n`` ids; ``reserve(k)`` fetches k new ones from the sequence
        (under the lock, so blocks are appended in sequence order)."""
        with self._lock:
            free = self._free
            if len(free) < n:
                free.extend(reserve(max(self.block, n - len(free))))
            taken = free[:n]
            del free[:n]
            return taken


def _write_rows(
    copy: psycopg.Copy, rids: list[int], entities: Sequence[EntitySample], sid_of: Callable[[SeriesKey], int]
) -> None:
    """One row per attribute, in SAMPLE_COLUMNS order (``_SAMPLE_TYPES``)."""
    for rid, entity in zip(rids, entities, strict=True):
        t = naive_utc(entity.time_index)
        prefix = (entity.tenant, entity.service_path, entity.entity_id, entity.entity_type)
        for a in entity.attrs:
            # SAMPLE_COLUMNS order, written out: ``common.content_values``'
            # two calls per attribute cost ~10% of PostgreSQL ingest.
            g = a.geo
            copy.write_row(
                (
                    rid,
                    sid_of((*prefix, a.name)),
                    t,
                    int(a.kind),
                    a.ngsi_type,
                    a.num,
                    a.txt,
                    a.js,
                    *(
                        (g.geojson, g.lon, g.lat, g.min_lon, g.min_lat, g.max_lon, g.max_lat)
                        if g is not None
                        else _NO_GEO
                    ),
                    a.md,
                    _naive(a.observed_at),
                    _naive(a.created_at),
                    _naive(a.modified_at),
                    _naive(a.deleted_at),
                )
            )


class PostgresAppender(StagingAppender):
    def __init__(self, store: PostgresStore):
        self._store = store
        self._conn = self._connect()
        self._found: dict[SeriesKey, int] = {}  # series the transaction being committed created
        self._reset()

    def _connect(self) -> psycopg.Connection:
        # Named, so an operator sees the writers in pg_stat_activity. In
        # autocommit: a group of samples alone is one COPY, its own
        # transaction (no BEGIN/COMMIT round trips); others BEGIN explicitly.
        return psycopg.connect(self._store.url, application_name=WRITER_APPLICATION_NAME, autocommit=True)

    def _connection(self) -> psycopg.Connection:
        """The writer's connection, replaced when it broke (a server restart,
        a network cut): otherwise one bad moment would fail every write after."""
        if self._conn.closed or self._conn.broken:
            with contextlib.suppress(psycopg.Error):
                self._conn.close()
            self._conn = self._connect()
        return self._conn

    def _reset(self) -> None:
        self._entities: list[EntitySample] = []
        self._dedup: list[bool] = []  # per entity: drop re-notified instances?
        self._latest: dict[SeriesKey, tuple | None] = {}  # this transaction's latest instance keys
        self._sids: dict[SeriesKey, int] = {}  # the batch's series ids
        self._rejected: list[RejectedNotification] = []
        self._layouts: list[PutLayout] = []
        self._deletes: list[DeleteSamples] = []
        self._instance_ops: list[DeleteInstance | ReplaceInstance] = []
        self._deliveries: list[Delivery] = []

    def _stage_samples(self, entities: Sequence[EntitySample], dedup: bool) -> None:
        self._entities.extend(entities)
        self._dedup.extend([dedup] * len(entities))

    def _stage_rejected(self, r: RejectedNotification) -> None:
        self._rejected.append(r)

    def _stage_delete(self, op: DeleteSamples) -> None:
        self._deletes.append(op)

    def _commit(self) -> None:
        conn = self._connection()
        if self._samples_alone():
            self._commit_samples_alone(conn)
        else:
            self._commit_transaction(conn)
        store = self._store
        store.layouts_committed(self._layouts)
        publish_staged(store.latest_instances, self._latest, self._sids.get)
        store.latest_instances.drop([sid for op in self._deletes for sid in op.sids])
        store.latest_instances.drop([op.sid for op in self._instance_ops])
        self._reset()

    def _samples_alone(self) -> bool:
        """Whether the group is the hot path's: plain samples of series this
        process knows committed, nothing that reads or writes other tables in
        the same transaction (deleted entities, NGSI-LD instances to
        de-duplicate, rejections, layouts, deletes, series to create)."""
        if not self._entities or self._rejected or self._layouts or self._deletes or self._instance_ops:
            return False
        if self._deliveries:  # recorded in the samples' transaction
            return False
        cache = self._store._series
        for e in self._entities:
            if e.deleted_at is not None:
                return False
            prefix = (e.tenant, e.service_path, e.entity_id, e.entity_type)
            for a in e.attrs:
                if a.observed_at is not None or (*prefix, a.name) not in cache:
                    return False
        return True

    def _commit_samples_alone(self, conn: psycopg.Connection) -> None:
        """One autocommit COPY: the statement is the transaction, so a group
        costs the COPY's two round trips. The extents the group grows are
        upserted first, in their own transaction: a crash in between leaves
        an extent larger than the stored positions, which only costs a few
        rows read (``extents``), never a missed sample."""
        with conn.cursor() as cur:
            extents_stored = self._store.geo_extents.record(cur, self._entities)
            extents_stored()
            self._store.untimed.record(cur, self._entities)(self._store._series)
            sids = self._store._series
            self._copy_rows(cur, self._entities, sids.__getitem__, autocommit=True)

    def _commit_transaction(self, conn: psycopg.Connection) -> None:
        """One transaction. Its opening statements go in one pipeline (one
        round trip): BEGIN, the batch's new series (insert, then read their
        ids: the SELECT starts after the INSERT waited out any concurrent
        writer of the same keys, so it sees them all) and the extents the
        batch grows. Reading a deleted entity's attributes comes before BEGIN:
        under READ COMMITTED every statement reads what was committed when it
        started, inside a transaction or not."""
        extents_stored = untimed_stored = None
        ids: dict[SeriesKey, int] = {}
        with conn.cursor() as cur, conn.cursor() as series_cur:
            if self._entities:
                self._entities = with_deletions(self._entities, lambda e: self._entity_attrs(cur, e))
            with conn.pipeline():
                cur.execute("BEGIN")
                if self._entities:
                    missing = self._send_series(series_cur)
                    extents_stored = self._store.geo_extents.record(cur, self._entities)
                    untimed_stored = self._store.untimed.record(cur, self._entities)
            if self._entities:
                ids = self._series_ids(series_cur, missing)
                self._copy_samples(cur, ids)
            for r in self._rejected:
                cur.execute(
                    f"INSERT INTO rejected_notifications ({REJECTED_INSERT_COLUMNS}) "
                    "VALUES (%s, %s, %s, %s, %s, %s, %s, %s, %s)",
                    rejected_values(r),
                )
            dropped = None
            if self._rejected:
                dropped = rejected_store.prune(
                    _fetch_all(cur),
                    rejected_store.POSTGRES,
                    [r.tenant for r in self._rejected],
                    self._store.rejected_limits,
                )
            for put in self._layouts:
                cur.execute(upsert_layout_sql("%s"), layout_values(put, datetime.now(UTC)))
            if self._deletes:
                self._delete(cur)
            for op in self._instance_ops:
                for sql, params in instance_statements(_DIALECT, ("samples",), op):
                    cur.execute(sql, params)
            for sql, params in delivery_statements("%s", self._deliveries):
                cur.execute(sql, params)
        self._send_commit(conn)
        if extents_stored is not None:
            extents_stored()
        if untimed_stored is not None:
            untimed_stored(ids)
        if dropped:
            rejected_store.count_dropped(self._store.rejected_dropped, dropped)

    def _delete(self, cur: psycopg.Cursor) -> None:
        """Deletes see only committed rows, so samples acknowledged after the
        delete was asked for survive it, as on DuckDB."""
        for op in self._deletes:
            for sql, params in delete_statements(_DIALECT, ("samples",), op.sids, TimeRange(op.start, op.end), 2**62):
                cur.execute(sql, params)

    def _copy_samples(self, cur: psycopg.Cursor, sids: dict[SeriesKey, int]) -> None:
        entities = self._without_renotified(cur, sids)
        if not entities:
            return
        self._copy_rows(cur, entities, lambda key: sids[key], autocommit=False)

    def _copy_rows(
        self,
        cur: psycopg.Cursor,
        entities: Sequence[EntitySample],
        sid_of: Callable[[SeriesKey], int],
        *,
        autocommit: bool,
    ) -> None:
        """COPY the entities' samples (one row id per entity). In autocommit
        the COPY commits when it ends: a connection that breaks after its end
        was sent may have committed it, so that is ``Unavailable``; before,
        the server rolls the unfinished COPY back and a retry is safe."""
        rids = self._store.row_ids.take(len(entities), _reserve(cur))
        ended = False
        try:
            with cur.copy(_COPY_SAMPLES) as copy:
                copy.set_types(_SAMPLE_TYPES)
                _write_rows(copy, rids, entities, sid_of)
                ended = True
        except psycopg.Error as exc:
            conn = cur.connection
            if autocommit and ended and (conn.broken or conn.closed):
                log.warning("connection lost while a COPY committed; outcome unknown: %s", exc)
                raise Unavailable(MAYBE_STORED) from exc
            raise

    def _entity_attrs(self, cur: psycopg.Cursor, entity: EntitySample) -> list[tuple[str, str | None]]:
        """Stored attributes (name, datasetId) of a deleted entity."""
        cur.execute(
            "SELECT attr, dataset_id FROM series WHERE tenant = %s AND service_path = %s AND entity_id = %s "
            "AND entity_type = %s ORDER BY attr",
            [entity.tenant, entity.service_path, entity.entity_id, entity.entity_type],
        )
        return cur.fetchall()

    def _without_renotified(self, cur: psycopg.Cursor, sids: dict[SeriesKey, int]) -> list[EntitySample]:
        """Drop NGSI-LD instances equal to their series' latest stored one."""
        entities = self._entities
        if not any(a.observed_at is not None for e in entities for a in e.attrs):
            return entities
        self._sids = sids
        items = []
        for e, dedup in zip(entities, self._dedup, strict=True):
            prefix = (e.tenant, e.service_path, e.entity_id, e.entity_type)
            for a in e.attrs:
                key = (*prefix, a.name)
                items.append((key, sids[key], a, dedup))

        def load(wanted: list[int]) -> dict:
            cur.execute(
                "SELECT l.* FROM unnest(%s::integer[]) AS s(sid) CROSS JOIN LATERAL ("
                "SELECT x.sid, x.observed_at, x.kind, x.num, x.txt, x.js, x.md, x.deleted_at FROM samples x "
                "WHERE x.sid = s.sid ORDER BY x.t DESC, x.iid DESC LIMIT 1) l",
                [int_array(wanted)],
            )
            return latest_keys(cur.fetchall())

        return without_dropped(entities, drop_renotified(items, self._store.latest_instances, self._latest, load))

    def _send_series(self, cur: psycopg.Cursor) -> list[SeriesKey]:
        """Send (in the caller's pipeline) the insert-if-absent of the batch's
        series this process does not know, and the read of their ids.
        Keys are inserted sorted so two replicas never lock in opposite
        orders. Returns the keys sent (``_series_ids`` reads the answer)."""
        cache = self._store._series
        wanted = {
            (e.tenant, e.service_path, e.entity_id, e.entity_type, a.name) for e in self._entities for a in e.attrs
        }
        missing = sorted(k for k in wanted if k not in cache)
        if missing:
            columns = [list(col) for col in zip(*missing, strict=True)]
            datasets = {
                (e.tenant, e.service_path, e.entity_id, e.entity_type, a.name): a.dataset_id
                for e in self._entities
                for a in e.attrs
                if a.dataset_id is not None
            }
            cur.execute(
                "INSERT INTO series (tenant, service_path, entity_id, entity_type, attr, dataset_id) "
                "SELECT * FROM unnest(%s::text[], %s::text[], %s::text[], %s::text[], %s::text[], %s::text[]) "
                "ON CONFLICT DO NOTHING",
                [*columns, [datasets.get(k) for k in missing]],
            )
            cur.execute(
                "SELECT s.sid, s.tenant, s.service_path, s.entity_id, s.entity_type, s.attr FROM series s "
                "JOIN unnest(%s::text[], %s::text[], %s::text[], %s::text[], %s::text[]) "
                "AS k(tenant, service_path, entity_id, entity_type, attr) USING "
                "(tenant, service_path, entity_id, entity_type, attr)",
                columns,
            )
        return missing

    def _series_ids(self, cur: psycopg.Cursor, missing: list[SeriesKey]) -> dict[SeriesKey, int]:
        """Series ids for every key in the batch: known ones from memory,
        ``missing`` ones from the SELECT ``_send_series`` sent."""
        cache = self._store._series
        local = {
            k: cache[k]
            for k in {
                (e.tenant, e.service_path, e.entity_id, e.entity_type, a.name) for e in self._entities for a in e.attrs
            }
            if k in cache
        }
        if missing:
            found = {tuple(row[1:]): row[0] for row in cur.fetchall()}
            local.update(found)
            self._found = found
        return local

    @staticmethod
    def _send_commit(conn: psycopg.Connection) -> None:
        """COMMIT, telling "rolled back" from "nobody knows": an error the
        server answered on a live connection means it rolled back (the caller
        may retry); a connection that broke meanwhile may have committed, and
        a retry could store the write twice, so that is ``Unavailable``."""
        try:
            conn.commit()
        except psycopg.Error as exc:
            if conn.broken or conn.closed:
                log.warning("connection lost during COMMIT; outcome unknown: %s", exc)
                raise Unavailable(MAYBE_STORED) from exc
            raise

    def commit(self) -> None:
        self._found = {}
        try:
            self._commit()
        except psycopg.Error as exc:
            self._store._note_write(exc)
            raise
        self._store._note_write(None)
        # Cache only after commit: only now do the rows this transaction
        # created certainly exist (a rolled-back series row would orphan samples).
        self._store._series.update(self._found)

    def rollback(self) -> None:
        # conn.rollback() sends ROLLBACK only inside a transaction (BEGIN
        # was explicit: the connection is in autocommit).
        with contextlib.suppress(psycopg.Error):
            self._conn.rollback()
        self._reset()

    def close(self) -> None:
        self._conn.close()
