"""Prometheus metrics: what an operator running us next to Orion watches
(served at ``GET /metrics`` by ``faces.operator.meta``).

Three sources, each hooked where it costs least:

* the **group committer** (``write.committer``) sees every write op once and
  every commit: notifications received / accepted / rejected / failed per
  tenant, commit latency and group size. It reports per group, from the
  writer thread, so the request path pays nothing;
* the **ASGI entry** (``TsdbApp.__call__``) times every HTTP request,
  labelled by route *template*: a raw path would give one time series per
  entity id, an unbounded label set that grows until Prometheus falls over;
* **scrape-time collectors**: the write queue depth, and the store and
  rejected-store sizes. The latter need the database, so the scrape runs in
  the threadpool (``Store.read``) and caches them for a few seconds: a
  burst of scrapes costs one query.

Each app has its own registry, so two apps in one process (tests) never mix
counts. The time-index fallback counters are the exception: the parser reports
through module-level hooks (``parse.timeindex.on_fallback``,
``on_stamp_fallback``), so those counters are per process and every app's
registry shows them.

Tenant labels are capped at ``max_tenants`` distinct values per app; later
tenants are counted under ``other``, and a tenant header the API refused
(kept as received with a refused notification, so chosen by whoever sent
it) under ``invalid``: labels carry only validated tenants. With ``--workers N`` every worker
process has its own counters (docs/operations.md, "Metrics").
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Iterable, Sequence
from typing import Any

from prometheus_client import (
    CollectorRegistry,
    Counter,
    Histogram,
    PlatformCollector,
    ProcessCollector,
    disable_created_metrics,
    generate_latest,
)
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily
from prometheus_client.registry import Collector

from tsdb_service.core import asgitiming
from tsdb_service.parse import timeindex
from tsdb_service.parse.request_context import is_stored_tenant
from tsdb_service.storage.store import Store
from tsdb_service.write.ops import AppendSamples, DeleteSamples, PutLayout, RecordRejected, WriteOp

log = logging.getLogger(__name__)

OTHER = "other"
INVALID = "invalid"  # the label of every tenant header the API refused
MAX_TENANTS = 100
STATS_TTL_S = 5.0
UNMATCHED = "(unmatched)"
METHODS = frozenset({"GET", "HEAD", "POST", "PUT", "PATCH", "DELETE", "OPTIONS"})

# Commits take from a fraction of a millisecond (DuckDB, small group) to
# tens of milliseconds (PostgreSQL over a network, big group).
COMMIT_BUCKETS = (0.0005, 0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5)
GROUP_BUCKETS = (1, 2, 4, 8, 16, 32, 64, 128, 256, 512, 1024, 2048, 4096)
REQUEST_BUCKETS = (0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 5.0, 10.0)

_KINDS = {AppendSamples: "samples", RecordRejected: "rejected", PutLayout: "layout", DeleteSamples: "delete"}

TIME_INDEX_FALLBACKS = Counter(
    "tsdb_time_index_fallbacks",
    "Notified entities stored at the reception time because they carried no usable time "
    "(counted when parsed, per process).",
    registry=None,
)
timeindex.on_fallback = TIME_INDEX_FALLBACKS.inc
TIME_INDEX_STAMP_FALLBACKS = Counter(
    "tsdb_time_index_stamp_fallbacks",
    "Attribute samples whose stamp (TSDB_TIME_INDEX_PATHS, or a value path in Fiware-TimeIndex-Attribute) "
    "could not be read, stored at the entity's time index instead (counted when parsed, per process).",
    registry=None,
)
timeindex.on_stamp_fallback = TIME_INDEX_STAMP_FALLBACKS.inc
# ``*_created`` timestamps double the series count and nothing here reads them.
disable_created_metrics()


class TenantLabels:
    """The first ``limit`` valid tenants seen keep their name; later ones are
    ``other``, refused tenant headers ``invalid``.

    Tenants are few in practice, but a label per distinct ``Fiware-Service``
    would let any client create series without bound."""

    def __init__(self, limit: int = MAX_TENANTS):
        self._limit = limit
        self._seen: set[str] = set()
        self._lock = threading.Lock()

    def __call__(self, tenant: str) -> str:
        if tenant in self._seen:
            return tenant
        if not is_stored_tenant(tenant):
            return INVALID
        with self._lock:
            if len(self._seen) < self._limit:
                self._seen.add(tenant)
                return tenant
        return OTHER


def _tenant_of(op: WriteOp) -> str | None:
    """The notification's tenant, or None for ops that are not notifications."""
    if type(op) is AppendSamples:
        entities = op.entities
        return entities[0].tenant if entities else ""
    if type(op) is RecordRejected:
        return op.rejected.tenant
    return None


class WriterMetrics:
    """The group committer's observer (``GroupCommitter.observer``).

    Called from writer threads once per group, never per request."""

    def __init__(self, registry: CollectorRegistry, tenants: TenantLabels):
        self._tenants = tenants
        self.received = Counter(
            "tsdb_notifications_received",
            "Notifications that reached the store's write queue (accepted + rejected + failed, once settled).",
            ["tenant"],
            registry=registry,
        )
        self.accepted = Counter(
            "tsdb_notifications_accepted", "Notifications committed and answered 200.", ["tenant"], registry=registry
        )
        self.rejected = Counter(
            "tsdb_notifications_rejected",
            "Notifications answered 4xx and kept in the rejected store, by error name.",
            ["tenant", "reason"],
            registry=registry,
        )
        self.failed = Counter(
            "tsdb_notifications_failed",
            "Notifications that could not be committed (answered 503; nothing stored).",
            ["tenant"],
            registry=registry,
        )
        self.commit_seconds = Histogram(
            "tsdb_commit_duration_seconds",
            "Time to stage and commit one group, by op kind.",
            ["kind"],
            buckets=COMMIT_BUCKETS,
            registry=registry,
        )
        self.group_size = Histogram(
            "tsdb_commit_group_size",
            "Ops committed together in one transaction, by op kind.",
            ["kind"],
            buckets=GROUP_BUCKETS,
            registry=registry,
        )
        self._per_kind: dict[str, tuple[Any, Any]] = {}
        self._children: dict[tuple, Any] = {}

    def _child(self, counter: Counter, *labels: str):
        """``counter.labels(...)``, memoised: ``labels`` takes a lock and
        validates on every call, this is one dict lookup."""
        key = (counter, labels)
        child = self._children.get(key)
        if child is None:
            child = self._children[key] = counter.labels(*labels)
        return child

    def _count(self, counter: Counter, ops: Iterable[WriteOp]) -> None:
        per_tenant: dict[str, int] = {}
        for op in ops:
            tenant = _tenant_of(op)
            if tenant is not None:
                per_tenant[tenant] = per_tenant.get(tenant, 0) + 1
        for tenant, n in per_tenant.items():
            self._child(counter, self._tenants(tenant)).inc(n)

    def taken(self, ops: Sequence[WriteOp]) -> None:
        self._count(self.received, ops)

    def committed(self, ops: Sequence[WriteOp], seconds: float) -> None:
        kind = _KINDS.get(type(ops[0]), "other")
        children = self._per_kind.get(kind)
        if children is None:
            children = self._per_kind[kind] = (self.commit_seconds.labels(kind), self.group_size.labels(kind))
        latency, size = children
        latency.observe(seconds)
        size.observe(len(ops))
        if kind == "samples":
            self._count(self.accepted, ops)
        elif kind == "rejected":
            for op in ops:
                if isinstance(op, RecordRejected):  # every op of this kind is
                    self._child(self.rejected, self._tenants(op.rejected.tenant), op.rejected.error).inc()

    def failed_ops(self, ops: Sequence[WriteOp]) -> None:
        self._count(self.failed, ops)


class RetentionMetrics:
    """The retention worker's observer (``storage.retention``), and its lag
    gauge at scrape time (from memory: no database call)."""

    def __init__(self, registry: CollectorRegistry, tenants: TenantLabels):
        self._tenants = tenants
        self.deleted = Counter(
            "tsdb_retention_deleted_rows",
            "Rows deleted by retention, by table (samples, samples_hot, rollups_minute, rollups_hour, "
            "rollups_hot_minute, rollups_hot_hour) and tenant; deleting raw samples leaves their rollups.",
            ["table", "tenant"],
            registry=registry,
        )
        self.batch_seconds = Histogram(
            "tsdb_retention_batch_duration_seconds",
            "Time of one retention batch (one transaction), by table.",
            ["table"],
            buckets=COMMIT_BUCKETS,
            registry=registry,
        )

    def batch(self, table: str, tenant: str, rows: int, seconds: float) -> None:
        self.deleted.labels(table, self._tenants(tenant)).inc(rows)
        self.batch_seconds.labels(table).observe(seconds)


class RetentionLagCollector(Collector):
    def __init__(self, worker):
        self._worker = worker

    def collect(self):
        family = GaugeMetricFamily(
            "tsdb_retention_watermark_lag_seconds",
            "How far the cutoff of the last completed retention pass trails the rule's cutoff now, per "
            "level (table: samples, minute, hour) and rule.",
            labels=["table", "rule"],
        )
        for (kind, rule), lag in sorted(self._worker.lags().items()):
            family.add_metric([kind, rule], lag)
        yield family


class RequestMetrics:
    """Request latency per route template, method and status."""

    def __init__(self, registry: CollectorRegistry):
        self.seconds = Histogram(
            "tsdb_http_request_duration_seconds",
            "HTTP request latency by route template, method and status.",
            ["route", "method", "status"],
            buckets=REQUEST_BUCKETS,
            registry=registry,
        )
        self._children: dict[tuple[str, str, int], Any] = {}

    def observe(self, scope, status: int, seconds: float, route: str | None = None) -> None:
        method = scope["method"]
        key = (route or _route_of(scope), method if method in METHODS else OTHER, status)
        child = self._children.get(key)
        if child is None:
            child = self._children[key] = self.seconds.labels(key[0], key[1], str(status))
        child.observe(seconds)

    async def timed(self, handler, scope, receive, send, route: str | None = None) -> None:
        """Run ``handler`` (an ASGI callable) and record how long it took;
        ``route`` names it when it bypasses the router (the notify fast path)."""
        await asgitiming.timed(
            handler, scope, receive, send, lambda status, seconds: self.observe(scope, status, seconds, route)
        )


def _route_of(scope) -> str:
    """The matched route's template (``/v2/entities/{entity_id}``), never the raw path."""
    route = scope.get("route")
    if route is None:
        return UNMATCHED
    return getattr(route, "path_format", None) or getattr(route, "path", None) or UNMATCHED


class StoreCollector(Collector):
    """Scrape-time gauges: write queue depth (memory) and store sizes (database,
    cached ``ttl`` seconds). ``collect`` may query the database: call it only
    from a thread, never on the event loop."""

    def __init__(self, store: Store, ttl: float = STATS_TTL_S):
        self._store = store
        self._ttl = ttl
        self._lock = threading.Lock()
        self._at = float("-inf")
        self._sizes: tuple[int, int, int] | None = None

    def collect(self):
        depth = getattr(_committer(self._store), "queue_depth", None)
        if depth is not None:
            yield GaugeMetricFamily(
                "tsdb_write_queue_depth", "Write ops queued, not yet taken by a writer.", value=depth
            )
        poisoned = getattr(_committer(self._store), "poisoned", None)
        if poisoned is not None:
            yield CounterMetricFamily(
                "tsdb_writes_poisoned",
                "Writes the database refused for their content again and again (NotStorable): never retried; "
                "the notification is kept in the rejected store.",
                value=poisoned,
            )
        yield from _ingest_log_metrics(getattr(self._store, "ingest_log", None))
        dropped = getattr(self._store, "rejected_dropped", None)
        if dropped is not None:
            family = CounterMetricFamily(
                "tsdb_rejected_dropped",
                "Rejected notifications dropped to keep the rejected store within its "
                "bounds (TSDB_REJECTED_MAX_*), by reason: count, bytes, age.",
                labels=["reason"],
            )
            for reason, n in sorted(dropped.items()):
                family.add_metric([reason], n)
            yield family
        sizes = self.sizes()
        if sizes is None:
            return
        store_bytes, rejected_rows, rejected_bytes = sizes
        yield GaugeMetricFamily(
            "tsdb_store_size_bytes",
            "Database size: DuckDB file + WAL, or PostgreSQL pg_database_size.",
            value=store_bytes,
        )
        yield GaugeMetricFamily(
            "tsdb_rejected_notifications", "Notifications kept in the rejected store.", value=rejected_rows
        )
        yield GaugeMetricFamily(
            "tsdb_rejected_store_bytes", "Bytes of raw bodies and headers in the rejected store.", value=rejected_bytes
        )

    def sizes(self) -> tuple[int, int, int] | None:
        """(store bytes, rejected rows, rejected bytes), at most ``ttl`` seconds old;
        None when the database cannot say (the scrape still answers)."""
        with self._lock:
            if time.monotonic() - self._at >= self._ttl:
                try:
                    self._sizes = self._store.sizes()
                except Exception as exc:  # a scrape must not fail because the database did
                    log.warning("store size unavailable: %s", exc)
                    self._sizes = None
                self._at = time.monotonic()
            return self._sizes


def _ingest_log_metrics(logged) -> Iterable:
    """The ingest log (``write.logged``): how far it runs ahead of the database."""
    if logged is None:
        return
    yield GaugeMetricFamily(
        "tsdb_ingest_log_lag_records",
        "Notification groups acknowledged in the ingest log and not yet applied to the database.",
        value=logged.acked_seq - logged.applied_seq,
    )
    yield GaugeMetricFamily(
        "tsdb_ingest_log_lag_bytes", "Encoded bytes acknowledged and not yet applied.", value=logged.lag_bytes
    )
    yield CounterMetricFamily(
        "tsdb_ingest_log_applied_batches", "Database transactions that applied the log.", value=logged.applied_batches
    )
    yield CounterMetricFamily(
        "tsdb_ingest_log_applied_samples", "Samples applied from the log.", value=logged.applied_samples
    )
    yield CounterMetricFamily(
        "tsdb_ingest_log_write_failures",
        "Groups of notifications the log could not write (disk full, directory not writable): each got 503.",
        value=logged.write_failures,
    )
    set_aside = logged.log.findings.set_aside
    yield CounterMetricFamily(
        "tsdb_ingest_log_set_aside_records",
        "Damaged ingest-log records (and every one after them) set aside in its quarantine folder at start.",
        value=0 if set_aside is None else set_aside.records,
    )
    yield CounterMetricFamily(
        "tsdb_ingest_log_set_aside_bytes",
        "Bytes of the ingest log set aside in its quarantine folder at start.",
        value=0 if set_aside is None else set_aside.bytes,
    )


class MqttCollector(Collector):
    """The MQTT consumer (``ingest.mqtt``), from memory at scrape time:
    anything with ``snapshot()`` giving the numbers below."""

    _COUNTERS = (
        ("received", "tsdb_mqtt_messages_received", "MQTT messages delivered to us (redeliveries included)."),
        ("connects", "tsdb_mqtt_connects", "Connections made to the MQTT broker (the first and every reconnection)."),
        ("write_retries", "tsdb_mqtt_write_retries", "Failed attempts to store an MQTT message (it is retried)."),
        (
            "sessions_lost",
            "tsdb_mqtt_sessions_lost",
            "Connections on which the MQTT broker had no session for us (the duplicate window starts afresh).",
        ),
    )
    _GAUGES = (
        ("connected", "tsdb_mqtt_connected", "1 while connected to the MQTT broker."),
        ("inflight", "tsdb_mqtt_inflight_messages", "MQTT messages received and not yet acknowledged."),
        ("buffered_bytes", "tsdb_mqtt_buffered_bytes", "Bytes of MQTT messages received and not yet stored."),
        (
            "oldest_unacked_s",
            "tsdb_mqtt_lag_seconds",
            "Age of the oldest MQTT message received and not yet acknowledged (0: none).",
        ),
    )

    def __init__(self, source):
        self._source = source

    def collect(self):
        numbers = self._source.snapshot()
        outcomes = CounterMetricFamily(
            "tsdb_mqtt_messages",
            "MQTT messages settled, by outcome: stored (samples written), rejected (kept in the rejected "
            "store), redelivered (a redelivery of one stored already: acknowledged, not stored again), "
            "poisoned (refused by the database for its content: kept in the rejected store).",
            labels=["outcome"],
        )
        for outcome in ("stored", "rejected", "redelivered", "poisoned"):
            outcomes.add_metric([outcome], numbers[outcome])
        yield outcomes
        for key, name, text in self._COUNTERS:
            yield CounterMetricFamily(name, text, value=numbers[key])
        for key, name, text in self._GAUGES:
            yield GaugeMetricFamily(name, text, value=numbers[key])


class IngestProcessesCollector(Collector):
    """The acceptor processes of ``--ingest-processes`` (``ingest.processes``)
    and the writes they relayed (``ingest.relay``), from memory at scrape time:
    anything with ``snapshot()`` giving the numbers below."""

    def __init__(self, source):
        self._source = source

    def collect(self):
        n = self._source.snapshot()
        yield GaugeMetricFamily(
            "tsdb_ingest_processes_running",
            "Acceptor processes running now (--ingest-processes - 1).",
            value=n["alive"],
        )
        yield CounterMetricFamily(
            "tsdb_ingest_process_restarts", "Acceptor processes started again after they died.", value=n["restarts"]
        )
        yield CounterMetricFamily(
            "tsdb_ingest_relayed_writes",
            "Writes acceptor processes relayed to this process (samples and refusals), answered.",
            value=n["relayed"],
        )


class ReadPoolCollector(Collector):
    """The reads in flight (``core.budget.ReadPool``), from memory at scrape time."""

    def __init__(self, pool):
        self._pool = pool

    def collect(self):
        n = self._pool.snapshot()
        yield GaugeMetricFamily("tsdb_read_slots_in_use", "Reads of the database running now.", value=n["slots_used"])
        yield GaugeMetricFamily(
            "tsdb_read_rows_in_flight",
            "Rows the reads running now hold (TSDB_READ_ROWS_IN_FLIGHT).",
            value=n["rows_used"],
        )
        yield GaugeMetricFamily("tsdb_read_waiting", "Reads waiting now for a free slot.", value=n["waiting"])
        yield CounterMetricFamily(
            "tsdb_read_queued", "Reads that had to wait for a slot or for room for their rows.", value=n["queued"]
        )
        yield CounterMetricFamily(
            "tsdb_read_refused",
            "Reads answered 503 ServerBusy after waiting TSDB_READ_QUEUE_SECONDS.",
            value=n["refused"],
        )


class _OtherOps:
    """An observer that passes on all but samples (counted at the ingest log)."""

    def __init__(self, inner: WriterMetrics):
        self._inner = inner

    def taken(self, ops: Sequence[WriteOp]) -> None:
        if rest := [op for op in ops if not isinstance(op, AppendSamples)]:
            self._inner.taken(rest)

    def committed(self, ops: Sequence[WriteOp], seconds: float) -> None:
        if rest := [op for op in ops if not isinstance(op, AppendSamples)]:
            self._inner.committed(rest, seconds)

    def failed_ops(self, ops: Sequence[WriteOp]) -> None:
        if rest := [op for op in ops if not isinstance(op, AppendSamples)]:
            self._inner.failed_ops(rest)


def _committer(store: Store):
    # Both stores show their group committer (``CommittingStore.committer``);
    # the seam has no accessor because nothing but metrics needs one.
    return getattr(store, "committer", None)


class Metrics:
    """One app's metrics: its registry, the writer observer and the request timer."""

    def __init__(self, max_tenants: int = MAX_TENANTS, stats_ttl: float = STATS_TTL_S):
        self._stats_ttl = stats_ttl
        self.registry = CollectorRegistry()
        self.tenants = TenantLabels(max_tenants)
        self.writer = WriterMetrics(self.registry, self.tenants)
        self.requests = RequestMetrics(self.registry)
        self.registry.register(TIME_INDEX_FALLBACKS)
        self.registry.register(TIME_INDEX_STAMP_FALLBACKS)
        # The standard process_* (CPU, memory, open files) and python_info series.
        ProcessCollector(registry=self.registry)
        PlatformCollector(registry=self.registry)
        self._store_collector: StoreCollector | None = None
        self.retention = RetentionMetrics(self.registry, self.tenants)
        self._retention_collector: RetentionLagCollector | None = None
        self._mqtt_collector: MqttCollector | None = None
        self._ingest_collector: IngestProcessesCollector | None = None

    def attach(self, store: Store) -> None:
        """Observe ``store``'s writers and report its sizes (called once the store is open).

        With an ingest log, notifications are counted (and their commit
        timed) when the log acknowledges them; the database writer then
        reports only the other ops, which go to it directly."""
        committer = _committer(store)
        logged = getattr(store, "ingest_log", None)
        if logged is not None:
            logged.observe(self.writer)
            if committer is not None:
                committer.observer = _OtherOps(self.writer)
        elif committer is not None:
            committer.observer = self.writer
        self._store_collector = StoreCollector(store, self._stats_ttl)
        self.registry.register(self._store_collector)
        worker = getattr(store, "retention", None)
        if worker is not None:
            worker.observer = self.retention
            self._retention_collector = RetentionLagCollector(worker)
            self.registry.register(self._retention_collector)

    def attach_read_pool(self, pool) -> None:
        """Report the process's read budget (``core.budget.ReadPool``)."""
        previous = getattr(self, "_read_pool_collector", None)
        if previous is not None:
            self.registry.unregister(previous)
        self._read_pool_collector = ReadPoolCollector(pool)
        self.registry.register(self._read_pool_collector)

    def attach_mqtt(self, consumer) -> None:
        """Report the MQTT consumer (``ingest.mqtt``) while it runs."""
        self._mqtt_collector = MqttCollector(consumer)
        self.registry.register(self._mqtt_collector)

    def attach_ingest_processes(self, source) -> None:
        """Report the acceptor processes (``ingest.processes``) while they run."""
        self._ingest_collector = IngestProcessesCollector(source)
        self.registry.register(self._ingest_collector)

    def detach_ingest_processes(self) -> None:
        if self._ingest_collector is not None:
            self.registry.unregister(self._ingest_collector)
            self._ingest_collector = None

    def detach_mqtt(self) -> None:
        if self._mqtt_collector is not None:
            self.registry.unregister(self._mqtt_collector)
            self._mqtt_collector = None

    def detach(self) -> None:
        if self._store_collector is not None:
            self.registry.unregister(self._store_collector)
            self._store_collector = None
        if self._retention_collector is not None:
            self.registry.unregister(self._retention_collector)
            self._retention_collector = None

    def render(self) -> bytes:
        """The exposition text. Blocking (store sizes): run it in a thread."""
        return generate_latest(self.registry)
