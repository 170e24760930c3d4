"""The DuckDB writer: stages a group's operations as columns and commits
them in one transaction (the samples and their rollups as Arrow batches),
then publishes what it wrote to memory.

The shape is ``storage.staging``'s, shared with the PostgreSQL writer. The
store is reached through ``DuckDBTarget``: its ids (``ids.SeriesIds``), its
memory (``memory.DuckDBMemory``), and the connection's public life (a
cursor of the current generation, used under ``writing``).
"""

from __future__ import annotations

import contextlib
import logging
from collections.abc import Sequence
from datetime import UTC, datetime
from typing import Any, Protocol

import duckdb
import pyarrow as pa

from tsdb_service.core.errors import Unavailable, first_line
from tsdb_service.core.model import EntitySample, RejectedNotification
from tsdb_service.core.query import TimeRange
from tsdb_service.storage import rejected as rejected_store
from tsdb_service.storage.columns import LD_TIME_COLUMNS, SAMPLE_COLUMNS, to_micros
from tsdb_service.storage.deliveries import delivery_statements
from tsdb_service.storage.duckdb.connection import (
    MAYBE_STORED,
    NOTHING_STORED,
    SAMPLE_TABLES,
    fatal_kind,
)
from tsdb_service.storage.duckdb.dialect import DuckDBDialect
from tsdb_service.storage.duckdb.ids import SeriesIds, SeriesKey
from tsdb_service.storage.duckdb.latest_geo import LATEST_GEO_SQL
from tsdb_service.storage.duckdb.memory import DuckDBMemory
from tsdb_service.storage.duckdb.state import ADVANCE_SQL
from tsdb_service.storage.layouts import layout_values, upsert_layout_sql
from tsdb_service.storage.ld_ingest import (
    LATEST_INSTANCE_SQL,
    drop_renotified,
    latest_keys,
    with_deletions,
    without_dropped,
)
from tsdb_service.storage.rollups import HOT, batch_partials
from tsdb_service.storage.sql.writes import delete_statements, instance_statements
from tsdb_service.storage.staging import StagingAppender, WriteTarget
from tsdb_service.write.ops import DeleteInstance, DeleteSamples, Delivery, LogPosition, PutLayout, ReplaceInstance

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


INSERT_SERIES = (
    "INSERT INTO series BY NAME SELECT unnest($1::INTEGER[]) AS sid, unnest($2::VARCHAR[]) AS tenant, "
    "unnest($3::VARCHAR[]) AS service_path, unnest($4::VARCHAR[]) AS entity_id, "
    "unnest($5::VARCHAR[]) AS entity_type, unnest($6::VARCHAR[]) AS attr, unnest($7::VARCHAR[]) AS dataset_id"
)


_DIALECT = DuckDBDialect()


def micros_or_none(moment: datetime | None) -> int | None:
    return None if moment is None else to_micros(moment)


class DuckDBTarget(WriteTarget, Protocol):
    """What a DuckDB writer needs of its store (``DuckDBStore`` is one)."""

    ids: SeriesIds
    memory: DuckDBMemory

    @property
    def generation(self) -> int:
        """Grows with every reopen; cursors of an older one are closed."""
        ...

    @property
    def invalid(self) -> bool:
        """The database instance is invalid until a reopen (nothing to recompute)."""
        ...

    def new_cursor(self) -> duckdb.DuckDBPyConnection: ...

    def writing(self) -> contextlib.AbstractContextManager[None]: ...

    def notice(self, exc: BaseException) -> str | None: ...

    def compactor_lock(self) -> contextlib.AbstractContextManager[Any]: ...


class DuckDBAppender(StagingAppender):
    """Turns staged ops into columnar batches; only the writer thread uses it."""

    def __init__(self, store: DuckDBTarget):
        self._store = store
        self._generation = store.generation
        self._cur = store.new_cursor()
        self._reset()
        # pyarrow imports pandas on its first array (about 0.2 s): at start-up
        # (the committer builds its writers before serving), not in the first
        # commit, which would keep the first notifications unapplied that long.
        pa.array([], pa.int64())

    def _current_cursor(self) -> duckdb.DuckDBPyConnection:
        """This writer's cursor on the store's current connection (a reopen
        closed the one made on the previous connection)."""
        store = self._store
        if self._generation != store.generation:
            self._generation = store.generation
            self._cur = store.new_cursor()
        return self._cur

    def _reset(self) -> None:
        self._cols: dict[str, list] = {name: [] for name in SAMPLE_SCHEMA.names}
        self._new_series: dict[SeriesKey, int] = {}  # series this group stages first (``ids.allocate``)
        self._new_datasets: dict[SeriesKey, str] = {}  # new series of non-default datasetIds
        self._latest: dict[SeriesKey, tuple | None] = {}  # this transaction's latest instance keys
        self._rejected: list[tuple] = []
        self._layouts: list[PutLayout] = []
        self._deletes: list[tuple[DeleteSamples, int]] = []
        self._instance_ops: list[DeleteInstance | ReplaceInstance] = []
        self._deliveries: list[Delivery] = []
        self._position: LogPosition | None = None  # the ingest log's, recorded with the samples (``state``)

    def _stage_log_position(self, position: LogPosition) -> None:
        held = self._position
        self._position = (
            position if held is None else LogPosition(max(held.seq, position.seq), max(held.rid, position.rid))
        )

    def _stage_delete(self, op: DeleteSamples) -> None:
        # Rows allocated after this op was staged (by any writer) survive it.
        self._deletes.append((op, self._store.ids.newest_rid()))

    def _stage_samples(self, entities: Sequence[EntitySample], dedup: bool) -> None:
        entities = with_deletions(entities, self._entity_attrs)
        entities = self._without_renotified(entities, dedup)
        rids, sids, first_iid = self._store.ids.allocate(entities, self._new_series)
        self._stage_columns(entities, rids, sids, first_iid)

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
        sid_of = self._store.ids.sid_of
        items = []
        for e in entities:
            prefix = (e.tenant, e.service_path, e.entity_id, e.entity_type)
            for a in e.attrs:
                key = (*prefix, a.name)
                items.append((key, sid_of(key) or self._new_series.get(key), a, dedup))
        latest_instances = self._store.memory.latest_instances
        return without_dropped(entities, drop_renotified(items, latest_instances, self._latest, self._latest_of))

    def _latest_of(self, sids: list[int]) -> dict:
        return latest_keys(
            self._cur.execute(
                LATEST_INSTANCE_SQL.format(table="samples_all", sids="sid IN (SELECT unnest(?::INTEGER[]))"), [sids]
            ).fetchall()
        )

    def _stage_columns(
        self, entities: Sequence[EntitySample], rids: list[int], sids: list[int], first_iid: int
    ) -> None:
        """Append the entities' samples to the staged columns, with the ids
        ``ids.allocate`` gave them (a row id per entity; a series id and an
        instance id per attribute, in order)."""
        c = self._cols
        rid_, t_, kind_, atype_, num_, txt_, js_, md_ = (
            c["rid"],
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
        obs_, cre_, mod_, del_ = c["observed_at"], c["created_at"], c["modified_at"], c["deleted_at"]
        c["sid"].extend(sids)
        c["iid"].extend(range(first_iid, first_iid + len(sids)))
        for entity, rid in zip(entities, rids, strict=True):
            micros = to_micros(entity.time_index)
            for attr in entity.attrs:
                rid_.append(rid)
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
                    obs_.append(micros_or_none(attr.observed_at))
                    cre_.append(micros_or_none(attr.created_at))
                    mod_.append(micros_or_none(attr.modified_at))
                    del_.append(micros_or_none(attr.deleted_at))
                    if attr.dataset_id is not None:
                        key = (entity.tenant, entity.service_path, entity.entity_id, entity.entity_type, attr.name)
                        if key in self._new_series:
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
        self._rejected.append((self._store.ids.rejected_id(), *rejected_store.insert_values(r)))

    def commit(self) -> None:
        """Commit the staged ops, or raise ``Unavailable`` saying whether
        anything may have been stored when the database instance is (or has
        just become) invalid: the group committer must not retry then.

        A commit whose automatic checkpoint failed is durable: it is
        published and acknowledged like any other, and the store reopens.
        """
        store = self._store
        with store.writing():
            try:
                self._commit(self._current_cursor())
            except duckdb.Error as exc:
                store.note_write(exc)
                kind = store.notice(exc)
                if kind == "refused":
                    raise Unavailable(NOTHING_STORED) from exc
                if kind is not None:
                    raise Unavailable(MAYBE_STORED) from exc
                raise
        store.note_write(None)

    def refuses(self, exc: BaseException) -> bool:
        """The content's fault: a value DuckDB cannot convert or hold, a
        constraint it breaks, or a value the appender cannot take (a plain
        Python error). An invalidated database, I/O and transaction
        conflicts pass: they are not."""
        if isinstance(exc, duckdb.Error):
            content = (
                duckdb.ConversionException,
                duckdb.InvalidInputException,
                duckdb.ConstraintException,
                duckdb.OutOfRangeException,
            )
            return isinstance(exc, content) and fatal_kind(exc) is None
        return isinstance(exc, ValueError | TypeError | OverflowError)

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
        log.warning("commit is durable but its checkpoint failed: %s", first_line(exc))
        self._store.notice(exc)
        return True

    def _commit(self, cur: duckdb.DuckDBPyConnection) -> None:
        """Make the staged ops durable with as few database calls as possible.

        Under load the event loop holds the GIL, and every return from
        DuckDB into Python waits for it; the writer holds it as little as it
        can. The staged columns become one Arrow batch (``_arrow_batch``:
        one C conversion a column, times from epoch microseconds), inserted
        by one statement that DuckDB plans and runs without the GIL; its
        rollups are computed from the same batch with numpy
        (``rollups.batch_partials``) and inserted the same way, in the same
        transaction. Against DuckDB's row appender it used before, this
        costs as much CPU at 60 samples a batch and half at 800, where
        the appender converted every value under the GIL
        (``benchmarks/apply_cpu.py``). New series
        rows are committed first; if the samples then fail, an unused series
        row is harmless. The ingest log's position goes in the samples'
        transaction (or, with no sample left to store, in the other one):
        never one without the other. Each transaction's samples reach memory
        right after it (``publish_samples``), the rest once the last one is
        in (``_publish``).
        """
        if self._new_series:
            self._store.ids.commit_series(self._new_series, lambda keys: self._insert_series(cur, keys))
            self._new_series = {}
        if self._cols["rid"]:
            self._commit_samples(cur)
            self._store.memory.publish_samples(self._cols)
        if (
            self._rejected
            or self._layouts
            or self._deletes
            or self._instance_ops
            or self._deliveries
            or self._position is not None
        ):
            # A delete must not race the compactor moving or rewriting the
            # same rows (its copy could resurrect them): hold its lock.
            changes = self._deletes or self._instance_ops
            guard = self._store.compactor_lock() if changes else contextlib.nullcontext()
            with guard:
                self._commit_other(cur)
        self._publish()

    def _insert_series(self, cur: duckdb.DuckDBPyConnection, keys: list[SeriesKey]) -> None:
        """The rows of new series ``keys`` (``ids.commit_series`` holds the series lock)."""
        self._durable(
            cur,
            INSERT_SERIES,
            [
                [self._new_series[k] for k in keys],
                *([k[i] for k in keys] for i in range(5)),
                [self._new_datasets.get(k) for k in keys],
            ],
        )

    def _commit_samples(self, cur: duckdb.DuckDBPyConnection) -> None:
        # The samples' rollups, MQTT deliveries and the ingest log's
        # position commit with the samples they came with: one explicit
        # transaction around them all (the appender joins it), so a
        # replayed batch is neither stored nor rolled up twice.
        deliveries, self._deliveries = self._deliveries, []
        position, self._position = self._position, None
        batch = self._arrow_batch()
        partials = batch_partials(batch)
        cur.execute("BEGIN")
        self._insert(cur, "samples_hot", batch)
        self._insert(cur, HOT, partials)
        for sql, params in delivery_statements("?", deliveries):
            cur.execute(sql, params)
        if position is not None:
            cur.execute(ADVANCE_SQL, [position.seq, position.rid])
        self._durable(cur, "COMMIT")

    def _arrow_batch(self) -> pa.Table:
        """The staged columns as one Arrow table (times from epoch
        microseconds, no datetime objects). A value a column cannot hold
        raises a plain Python error (``refuses``), before any statement."""
        cols = self._cols
        arrays = [
            pa.array(cols[f.name], pa.int64()).cast(f.type)
            if f.name in TIME_COLUMNS
            else pa.array(cols[f.name], f.type)
            for f in SAMPLE_SCHEMA
        ]
        return pa.Table.from_arrays(arrays, schema=SAMPLE_SCHEMA)

    def _insert(self, cur: duckdb.DuckDBPyConnection, table: str, arrow_rows: pa.Table) -> None:
        """``arrow_rows`` into ``table`` by column name, in the open
        transaction: one statement, which DuckDB plans and runs without the
        GIL. It reads the local variable by its name (DuckDB's replacement
        scan: no view to register and drop, which cost as much again)."""
        cur.execute(f"INSERT INTO {table} BY NAME SELECT * FROM arrow_rows")

    def _commit_other(self, cur: duckdb.DuckDBPyConnection) -> None:
        cur.execute("BEGIN")
        for row in self._rejected:
            cur.execute(
                f"INSERT INTO rejected_notifications (id, {rejected_store.INSERT_COLUMNS}) "
                "VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
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
                _DIALECT, SAMPLE_TABLES, op.sids, TimeRange(op.start, op.end), upto_rid
            ):
                cur.execute(sql, params)
        for instance_op in self._instance_ops:
            for sql, params in instance_statements(_DIALECT, SAMPLE_TABLES, instance_op):
                cur.execute(sql, params)
        for sql, params in delivery_statements("?", self._deliveries):
            cur.execute(sql, params)
        if self._position is not None:
            cur.execute(ADVANCE_SQL, [self._position.seq, self._position.rid])
        self._durable(cur, "COMMIT")
        if dropped:
            rejected_store.count_dropped(self._store.rejected_dropped, dropped)

    def _latest_geo_of(self, sids: list[int]) -> list[tuple]:
        return self._cur.execute(
            LATEST_GEO_SQL.format(where="AND sid IN (SELECT unnest(?::INTEGER[]))"), [sids]
        ).fetchall()

    def _publish(self) -> None:
        """Expose only what is durable: series a delete or an instance edit
        touched are forgotten (and relocated, unless the reopen rebuilds
        every location), then the group's latest instances and layouts."""
        store = self._store
        memory, ids = store.memory, store.ids
        for op, upto_rid in self._deletes:
            memory.forget(op.sids)
            if not store.invalid:
                memory.relocate(op.sids, upto_rid, self._latest_geo_of)
        for instance_op in self._instance_ops:
            memory.forget([instance_op.sid])
            if not store.invalid:
                memory.relocate([instance_op.sid], ids.newest_rid(), self._latest_geo_of)
        memory.publish_instances(self._latest, ids.sid_of)
        memory.publish_layouts(self._layouts)
        self._reset()

    def rollback(self) -> None:
        # Ids staged for new series stay pending (``ids``): the next writer
        # to see those keys inserts their rows.
        store = self._store
        try:
            with store.writing():
                if self._generation == store.generation:
                    self._cur.execute("ROLLBACK")
        except (duckdb.Error, Unavailable):
            pass  # no transaction was open, or the connection is being replaced
        self._reset()

    def close(self) -> None:
        with contextlib.suppress(duckdb.Error):
            self._cur.close()
