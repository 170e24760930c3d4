"""The PostgreSQL writer: stages a group's operations and commits them in
one transaction, samples sent with binary ``COPY``, then publishes what it
wrote to memory.

The shape is ``storage.staging``'s, shared with the DuckDB writer. A group
of plain samples of series this process knows is a single autocommit
``COPY`` (two round trips); others open a transaction whose first statements
share one pipeline round trip. Row ids come from blocks reserved from the
sequence (``ids.RowIds``). Series ids are shared through the ``series``
table (insert-if-absent, in key order so concurrent writers cannot
deadlock). The store is reached through ``PostgresTarget``: its ids
(``ids.PostgresIds``), its memory (``memory.PostgresMemory``) and its URL.

A failed write is answered "nothing was stored" only when the transaction
certainly did not commit: an error before COMMIT, or one the server raised
for the COMMIT itself on a live connection (the server rolled back). When the
connection breaks during COMMIT (or once an autocommit COPY's end was sent)
nobody can say, and the answer says so.
"""

from __future__ import annotations

import contextlib
import logging
from collections.abc import Callable, Sequence
from datetime import UTC, datetime
from typing import Protocol

import psycopg

from tsdb_service.core.errors import Unavailable
from tsdb_service.core.model import EntitySample, RejectedNotification
from tsdb_service.core.query import TimeRange
from tsdb_service.storage import rejected as rejected_store
from tsdb_service.storage.columns import GEO_COLUMNS, LD_TIME_COLUMNS, NO_GEO, SAMPLE_COLUMNS, naive_utc
from tsdb_service.storage.deliveries import delivery_statements
from tsdb_service.storage.layouts import layout_values, upsert_layout_sql
from tsdb_service.storage.ld_ingest import drop_renotified, latest_keys, with_deletions, without_dropped
from tsdb_service.storage.postgres.dialect import PostgresDialect, int_array
from tsdb_service.storage.postgres.ids import PostgresIds, SeriesKey
from tsdb_service.storage.postgres.memory import PostgresMemory
from tsdb_service.storage.sql.writes import delete_statements, instance_statements
from tsdb_service.storage.staging import StagingAppender, WriteTarget
from tsdb_service.write.ops import DeleteInstance, DeleteSamples, Delivery, PutLayout, ReplaceInstance

log = logging.getLogger(__name__)

# SAMPLE_COLUMNS (``storage.columns``): iid is the column default's (a sequence).
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
WRITER_APPLICATION_NAME = "tsdb-service writer"
MAYBE_STORED = "the connection to the database broke during the commit; this write may or may not have been stored"


class PostgresTarget(WriteTarget, Protocol):
    """What a PostgreSQL writer needs of its store (``PostgresStore`` is one)."""

    url: str
    ids: PostgresIds
    memory: PostgresMemory


def _naive(moment: datetime | None) -> datetime | None:
    return None if moment is None else naive_utc(moment)


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


def _write_rows(
    copy: psycopg.Copy, rids: list[int], entities: Sequence[EntitySample], sid_of: Callable[[SeriesKey], int]
) -> None:
    """One row per attribute, in SAMPLE_COLUMNS order (``_SAMPLE_TYPES``)."""
    for rid, entity in zip(rids, entities, strict=True):
        t = naive_utc(entity.time_index)
        prefix = (entity.tenant, entity.service_path, entity.entity_id, entity.entity_type)
        for a in entity.attrs:
            # SAMPLE_COLUMNS order, written out: ``columns.content_values``'
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
                        else NO_GEO
                    ),
                    a.md,
                    _naive(a.observed_at),
                    _naive(a.created_at),
                    _naive(a.modified_at),
                    _naive(a.deleted_at),
                )
            )


class PostgresAppender(StagingAppender):
    """Stages a group's operations for one transaction; only the writer thread uses it."""

    def __init__(self, store: PostgresTarget):
        self._store = store
        self._conn = self._connect()
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
        self._found: dict[SeriesKey, int] = {}  # series the transaction being committed created or read back
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

    def commit(self) -> None:
        """Commit the staged ops, or raise and leave nothing; ``Unavailable``
        when nobody can say whether they were stored (``MAYBE_STORED``)."""
        store = self._store
        try:
            self._commit(self._connection())
        except psycopg.Error as exc:
            store.note_write(exc)
            raise
        store.note_write(None)

    def _commit(self, conn: psycopg.Connection) -> None:
        """One autocommit COPY when the group is plain samples of known
        series, else one transaction; then ``_publish``."""
        sids = self._known_sids()
        if sids is not None:
            self._commit_samples_alone(conn, sids)
        else:
            self._commit_transaction(conn)
        self._publish()

    def _known_sids(self) -> dict[SeriesKey, int] | None:
        """The batch's series ids when the group is the hot path's: plain
        samples of series this process knows committed, nothing that reads
        or writes other tables in the same transaction (deleted entities,
        NGSI-LD instances to de-duplicate, rejections, layouts, deletes,
        series to create); else None."""
        if not self._entities or self._rejected or self._layouts or self._deletes or self._instance_ops:
            return None
        if self._deliveries:  # recorded in the samples' transaction
            return None
        sid_of = self._store.ids.sid_of
        sids: dict[SeriesKey, int] = {}
        for e in self._entities:
            if e.deleted_at is not None:
                return None
            prefix = (e.tenant, e.service_path, e.entity_id, e.entity_type)
            for a in e.attrs:
                key = (*prefix, a.name)
                sid = sid_of(key)
                if a.observed_at is not None or sid is None:
                    return None
                sids[key] = sid
        return sids

    def _commit_samples_alone(self, conn: psycopg.Connection, sids: dict[SeriesKey, int]) -> None:
        """One autocommit COPY: the statement is the transaction, so a group
        costs the COPY's two round trips. The extents the group grows are
        upserted first, in their own transaction: a crash in between leaves
        an extent larger than the stored positions, which only costs a few
        rows read (``extents``), never a missed sample."""
        memory = self._store.memory
        with conn.cursor() as cur:
            extents_stored = memory.extents.record(cur, self._entities)
            extents_stored()
            memory.untimed.record(cur, self._entities)(sids)
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
        memory = self._store.memory
        with conn.cursor() as cur, conn.cursor() as series_cur:
            if self._entities:
                self._entities = with_deletions(self._entities, lambda e: self._entity_attrs(cur, e))
            with conn.pipeline():
                cur.execute("BEGIN")
                if self._entities:
                    missing = self._send_series(series_cur)
                    extents_stored = memory.extents.record(cur, self._entities)
                    untimed_stored = memory.untimed.record(cur, self._entities)
            if self._entities:
                ids = self._series_ids(series_cur, missing)
                self._copy_samples(cur, ids)
            for r in self._rejected:
                cur.execute(
                    f"INSERT INTO rejected_notifications ({rejected_store.INSERT_COLUMNS}) "
                    "VALUES (%s, %s, %s, %s, %s, %s, %s, %s, %s)",
                    rejected_store.insert_values(r),
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
        rids = self._store.ids.take_rids(len(entities), _reserve(cur))
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

        latest_instances = self._store.memory.latest_instances
        return without_dropped(entities, drop_renotified(items, latest_instances, self._latest, load))

    def _send_series(self, cur: psycopg.Cursor) -> list[SeriesKey]:
        """Send (in the caller's pipeline) the insert-if-absent of the batch's
        series this process does not know, and the read of their ids.
        Keys are inserted sorted so two replicas never lock in opposite
        orders. Returns the keys sent (``_series_ids`` reads the answer)."""
        sid_of = self._store.ids.sid_of
        wanted = {
            (e.tenant, e.service_path, e.entity_id, e.entity_type, a.name) for e in self._entities for a in e.attrs
        }
        missing = sorted(k for k in wanted if sid_of(k) is None)
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
        sid_of = self._store.ids.sid_of
        wanted = {
            (e.tenant, e.service_path, e.entity_id, e.entity_type, a.name) for e in self._entities for a in e.attrs
        }
        local = {k: sid for k in wanted if (sid := sid_of(k)) is not None}
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

    def _publish(self) -> None:
        """Expose only what is durable: the series the transaction created
        or read back (only now do their rows certainly exist: a rolled-back
        series row would orphan samples), its latest instances and layouts;
        series a delete or an instance edit touched are forgotten."""
        store = self._store
        memory = store.memory
        store.ids.publish_series(self._found)
        memory.publish_instances(self._latest, self._sids.get)
        memory.publish_layouts(self._layouts)
        memory.forget([sid for op in self._deletes for sid in op.sids])
        memory.forget([op.sid for op in self._instance_ops])
        self._reset()

    def refuses(self, exc: BaseException) -> bool:
        """The content's fault: a value PostgreSQL cannot hold or convert
        (class 22, data exception, e.g. a NUL in text), a constraint it
        breaks (class 23), or a value the driver cannot send. A lost
        connection, a full disk, a conflict pass: they are not."""
        if isinstance(exc, psycopg.Error):
            return isinstance(exc, psycopg.DataError | psycopg.IntegrityError)
        return isinstance(exc, ValueError | TypeError | OverflowError)

    def rollback(self) -> None:
        # conn.rollback() sends ROLLBACK only inside a transaction (BEGIN
        # was explicit: the connection is in autocommit).
        with contextlib.suppress(psycopg.Error):
            self._conn.rollback()
        self._reset()

    def close(self) -> None:
        self._conn.close()
