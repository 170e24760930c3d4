"""What both backends' stores and appenders share, written once.

The sample columns and how an attribute fills them, the bounding-box
prefilter (in SQL and in memory), the ``values``-layout rows, the write
delegation to the group committer, ``/health``, and the appender's dispatch
over ``WriteOp`` types. The backend packages (``storage.duckdb``,
``storage.postgres``) import this module; it imports neither of them.
"""

from __future__ import annotations

import json
from abc import abstractmethod
from collections.abc import Iterable, Sequence
from datetime import UTC, datetime, timedelta
from typing import Any

import orjson

from tsdb_service.core.model import AttrSample, EntitySample, RejectedNotification
from tsdb_service.core.query import WITHIN, Prefilter
from tsdb_service.parse import ValuesLayout
from tsdb_service.storage.store import CopyRun, Store
from tsdb_service.write.appender import Appender
from tsdb_service.write.committer import GroupCommitter
from tsdb_service.write.logged import LoggedWriter
from tsdb_service.write.ops import (
    AppendSamples,
    DeleteInstance,
    DeleteSamples,
    Delivery,
    PutLayout,
    RecordRejected,
    ReplaceInstance,
    WriteOp,
)

# -- sample columns ----------------------------------------------------------------

GEO_COLUMNS = ("geo", "lon", "lat", "min_lon", "min_lat", "max_lon", "max_lat")
# What an attribute instance's content fills (a replacement rewrites these).
VALUE_COLUMNS = ("kind", "atype", "num", "txt", "js", *GEO_COLUMNS, "md")
LD_TIME_COLUMNS = ("observed_at", "created_at", "modified_at", "deleted_at")
# Every stored column but the instance id, which each store allocates itself.
SAMPLE_COLUMNS = ("rid", "sid", "t", *VALUE_COLUMNS, *LD_TIME_COLUMNS)
_NO_GEO = (None,) * len(GEO_COLUMNS)

EPOCH = datetime(1970, 1, 1, tzinfo=UTC)
ONE_US = timedelta(microseconds=1)
_NAIVE_EPOCH = datetime(1970, 1, 1)


def content_values(a: AttrSample) -> tuple:
    """``VALUE_COLUMNS`` of an attribute sample (the geometry's columns all
    None without one). Not for per-row loops: the COPY and Arrow paths write
    the same order out in place."""
    g = a.geo
    geo = _NO_GEO if g is None else (g.geojson, g.lon, g.lat, g.min_lon, g.min_lat, g.max_lon, g.max_lat)
    return (int(a.kind), a.ngsi_type, a.num, a.txt, a.js, *geo, a.md)


def to_micros(moment: datetime) -> int:
    """Exact microseconds since the epoch (float timestamps lose precision)."""
    return (moment - EPOCH) // ONE_US


def naive_timestamps(micros: Iterable[int | None]) -> list[datetime | None]:
    """``to_micros``' inverse over a column, as the naive UTC datetimes a
    TIMESTAMP column holds (a DuckDB appender takes no integers there);
    exact, unlike a float division."""
    epoch, delta = _NAIVE_EPOCH, timedelta
    return [None if v is None else epoch + delta(microseconds=v) for v in micros]


def naive_utc(moment: datetime) -> datetime:
    """A timezone-aware moment as the naive UTC timestamp the columns hold."""
    return moment.astimezone(UTC).replace(tzinfo=None)


# -- the bounding-box prefilter (``core.query``: ``box_passes``) -------------------------------


def box_sql(placeholder: str, prefilter: Prefilter | None) -> tuple[str, list]:
    """SQL over the columns min_lon... : the stored box passes ``prefilter``
    (None passes everything)."""
    if prefilter is None:
        return "TRUE", []
    how, box = prefilter
    p = placeholder
    if how == WITHIN:
        sql = f"(min_lon >= {p} AND max_lon <= {p} AND min_lat >= {p} AND max_lat <= {p})"
    else:
        sql = f"(max_lon >= {p} AND min_lon <= {p} AND max_lat >= {p} AND min_lat <= {p})"
    return sql, [box.min_lon, box.max_lon, box.min_lat, box.max_lat]


# -- values layouts --------------------------------------------------------------------

LOAD_LAYOUTS_SQL = "SELECT tenant, subscription_id, attrs, entity_id, entity_type FROM subscriptions"


def layouts_from_rows(rows: Iterable[tuple]) -> dict[tuple[str, str], ValuesLayout]:
    """``LOAD_LAYOUTS_SQL`` rows by (tenant, subscription id)."""
    return {
        (tenant, sub): ValuesLayout(tuple(orjson.loads(attrs)), eid, etype) for tenant, sub, attrs, eid, etype in rows
    }


def layout_values(put: PutLayout, now: datetime) -> list:
    """A ``subscriptions`` row, in column order."""
    layout = put.layout
    return [
        put.tenant,
        put.subscription_id,
        orjson.dumps(list(layout.attrs)).decode(),
        layout.entity_id,
        layout.entity_type,
        naive_utc(now),
    ]


def upsert_layout_sql(p: str) -> str:
    return (
        f"INSERT INTO subscriptions VALUES ({p}, {p}, {p}, {p}, {p}, {p}) "
        "ON CONFLICT (tenant, subscription_id) DO UPDATE SET attrs = EXCLUDED.attrs, "
        "entity_id = EXCLUDED.entity_id, entity_type = EXCLUDED.entity_type, "
        "registered_at = EXCLUDED.registered_at"
    )


REJECTED_INSERT_COLUMNS = "tenant, received_at, error, description, headers, body, body_size, body_truncated, topic"


def rejected_values(r: RejectedNotification) -> tuple:
    """A ``rejected_notifications`` row (``REJECTED_INSERT_COLUMNS``)."""
    size = len(r.body) if r.body_size is None else r.body_size
    return (
        r.tenant,
        naive_utc(r.received_at),
        r.error,
        r.description,
        r.headers,
        r.body,
        size,
        r.body_truncated,
        r.topic,
    )


# -- MQTT deliveries (``ingest.mqtt``; migration 0012) ----------------------------------

_DELIVERY_ROWS = 500  # rows per INSERT statement
DELIVERY_COLUMNS = "client_id, seq, packet_id, digest, received_at"


def delivery_statements(p: str, deliveries: Sequence[Delivery]) -> list[tuple[str, list]]:
    """Record ``deliveries`` (in the caller's transaction, with what they
    stored): INSERTs that skip a delivery recorded already (an ingest-log
    replay may apply one twice), then the DELETEs their ``prune_below`` ask for."""
    out: list[tuple[str, list]] = []
    row = f"({p}, {p}, {p}, {p}, {p})"
    for start in range(0, len(deliveries), _DELIVERY_ROWS):
        chunk = deliveries[start : start + _DELIVERY_ROWS]
        params: list = []
        for d in chunk:
            params += [d.client_id, d.seq, d.packet_id, d.digest, naive_utc(d.received_at)]
        values = ", ".join([row] * len(chunk))
        out.append((f"INSERT INTO mqtt_deliveries ({DELIVERY_COLUMNS}) VALUES {values} ON CONFLICT DO NOTHING", params))
    prune: dict[str, int] = {}
    for d in deliveries:
        if d.prune_below:
            prune[d.client_id] = max(prune.get(d.client_id, 0), d.prune_below)
    for client_id, below in sorted(prune.items()):
        out.append((f"DELETE FROM mqtt_deliveries WHERE client_id = {p} AND seq < {p}", [client_id, below]))
    return out


# The newest deliveries of one client id, newest first: (seq, packet id, digest).
RECENT_DELIVERIES_SQL = (
    "SELECT seq, packet_id, digest FROM mqtt_deliveries WHERE client_id = ? ORDER BY seq DESC LIMIT ?"
)


def without_dropped(entities: Sequence[EntitySample], keep: Iterable[bool]) -> list[EntitySample]:
    """``entities`` without the attributes ``keep`` (one flag per attribute,
    in order) drops; an entity left without attributes goes too."""
    flags = iter(keep)
    out = []
    for e in entities:
        attrs = [a for a in e.attrs if next(flags)]
        if attrs:
            out.append(
                e
                if len(attrs) == len(e.attrs)
                else EntitySample(
                    e.tenant, e.service_path, e.entity_id, e.entity_type, e.time_index, attrs, e.deleted_at, e.rid
                )
            )
    return out


# -- the store and appender halves both backends share ----------------------------------


class CommittingStore(Store):
    """A store whose writes go through one ``GroupCommitter``."""

    _committer: GroupCommitter
    _layouts: dict[tuple[str, str], ValuesLayout]
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

    def layouts(self, tenant: str) -> dict[str, ValuesLayout]:
        return {sub: layout for (t, sub), layout in list(self._layouts.items()) if t == tenant}

    def health(self) -> dict[str, Any]:
        """``pass`` while the writers run and the database takes writes (and
        whatever ``_health_problem`` checks)."""
        problem = self._health_problem()
        if problem is None and self._write_failure is not None:
            problem = "the database refuses writes: " + self._write_failure
        logged = self._logged
        if problem is None and logged is not None and logged.failure is not None:
            problem = logged.failure
        alive = self._committer.alive and (logged is None or logged.alive)
        ok = alive and problem is None and self._reachable()
        report: dict[str, Any] = {
            "status": "pass" if ok else "fail",
            "backend": self.backend,
            "commits": self._committer.commits,
            "writes": self._committer.ops,
        }
        if problem is not None:
            report["output"] = problem
        return report

    def _health_problem(self) -> str | None:
        """A backend's own reason to fail ``/health``, worded for an operator."""
        return None

    def _reachable(self) -> bool:
        """Whether the database answers (a backend probes it if it can be away)."""
        return True

    def _note_write(self, exc: BaseException | None) -> None:
        """Remember whether the database takes writes, for /health."""
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


def first_line(exc: BaseException) -> str:
    return str(exc).strip().splitlines()[0][:300] if str(exc).strip() else type(exc).__name__


class StagingAppender(Appender):
    """The dispatch over ``WriteOp`` types; a backend stages each kind."""

    _layouts: list[PutLayout]
    _instance_ops: list[DeleteInstance | ReplaceInstance]
    _deliveries: list[Delivery]  # committed with the samples or rejections staged beside them

    def stage(self, op: WriteOp) -> None:
        if isinstance(op, AppendSamples):
            self._stage_samples(op.entities, op.dedup)
            self._deliveries.extend(op.deliveries)
        elif isinstance(op, RecordRejected):
            self._stage_rejected(op.rejected)
            if op.delivery is not None:
                self._deliveries.append(op.delivery)
        elif isinstance(op, PutLayout):
            self._layouts.append(op)
        elif isinstance(op, DeleteSamples):
            self._stage_delete(op)
        elif isinstance(op, (DeleteInstance, ReplaceInstance)):
            self._instance_ops.append(op)
        else:  # pragma: no cover - programming error
            raise TypeError(f"unknown write op {op!r}")

    @abstractmethod
    def _stage_samples(self, entities: Sequence[EntitySample], dedup: bool) -> None: ...

    @abstractmethod
    def _stage_rejected(self, r: RejectedNotification) -> None: ...

    @abstractmethod
    def _stage_delete(self, op: DeleteSamples) -> None: ...
