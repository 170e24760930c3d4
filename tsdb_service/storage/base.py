"""The storage seam: what routes may ask of a backend.

Modelled on Prometheus' storage interface: writes go through an *appender*
(stage a batch, then commit it atomically), reads through a *querier*. Routes
never see SQL; DuckDB and PostgreSQL each implement both halves, in their
packages (``storage.duckdb``, ``storage.postgres``), on the shared pieces
of ``storage.common`` and ``storage.sql``. The seam speaks the query
vocabulary of ``tsdb_service.core.query``: what a read asks for and the named
rows it returns.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable, Collection, Iterable, Iterator, Sequence
from contextlib import AbstractContextManager
from dataclasses import dataclass
from datetime import datetime
from typing import TYPE_CHECKING, Any

from tsdb_service.core.model import AttrSample, EntitySample, RejectedNotification
from tsdb_service.core.query import (
    AggBranch,
    AggregateRow,
    Aggregation,
    EntityFilter,
    ExtentRow,
    FirstLocationRow,
    GeometryRow,
    InstanceAggregateRow,
    InstancePeriods,
    InstanceRow,
    InstanceValueRow,
    InstanceWindow,
    LastValueRow,
    LatestRow,
    LocationProbe,
    LocationRow,
    Prefilter,
    RawRow,
    RowMask,
    Scope,
    SeriesRef,
    StoredSample,
    TimeRange,
    ValueProbe,
    ValueTest,
    WindowScan,
)
from tsdb_service.parse import ValuesLayout
from tsdb_service.read.off_loop import T, read_off_loop

if TYPE_CHECKING:
    from tsdb_service.storage.export import SampleBatches


@dataclass(frozen=True, slots=True)
class AppendSamples:
    """Store samples. ``dedup``: drop NGSI-LD instances that repeat their
    series' latest stored one (see ``storage.ld_ingest``); off for copies,
    which must reproduce the source exactly."""

    entities: Sequence[EntitySample]
    dedup: bool = True


@dataclass(frozen=True, slots=True)
class RecordRejected:
    rejected: RejectedNotification


@dataclass(frozen=True, slots=True)
class PutLayout:
    tenant: str
    subscription_id: str
    layout: ValuesLayout


@dataclass(frozen=True, slots=True)
class DeleteSamples:
    """Delete the samples of some series, optionally within a time range
    (inclusive, timezone-aware). Samples written after the delete was
    acknowledged are never touched. Series rows are kept."""

    sids: tuple[int, ...]
    start: datetime | None = None
    end: datetime | None = None


@dataclass(frozen=True, slots=True)
class DeleteInstance:
    """Delete one NGSI-LD attribute instance (sample ``iid`` of series ``sid``)."""

    sid: int
    iid: int


@dataclass(frozen=True, slots=True)
class ReplaceInstance:
    """Replace the content of one NGSI-LD attribute instance in place: its
    instance id, series and row time stay; value, type, sub-properties and
    observedAt become ``attr``'s (observedAt only when ``attr`` has one),
    and ``modified_at`` is set."""

    sid: int
    iid: int
    attr: AttrSample
    modified_at: datetime


WriteOp = AppendSamples | RecordRejected | PutLayout | DeleteSamples | DeleteInstance | ReplaceInstance


class Appender(ABC):
    """Stages write operations and commits them as one transaction.

    Owned by exactly one writer thread; never shared.
    """

    @abstractmethod
    def stage(self, op: WriteOp) -> None: ...

    @abstractmethod
    def commit(self) -> None:
        """Make everything staged durable, or raise and leave nothing."""

    @abstractmethod
    def rollback(self) -> None: ...

    def close(self) -> None:  # noqa: B027 - optional hook
        pass


class Querier(ABC):
    """The read half of the seam: history reads by series id.

    ``storage.sql.SqlQuerier`` implements it for both SQL backends. One per
    store (``Store.querier()``), shared by every thread.

    **Threads and lifetimes** (as Prometheus' ``storage.Querier`` states
    them). Every method is safe to call from any number of threads at once.
    Unless its docstring says *memory only*, a method may query the
    database: call it from a worker thread (the threadpool, a writer, a
    command), never on the event loop. Each call is its own snapshot of
    committed data (a write acknowledged before the call is in it, one
    committed meanwhile may or may not be). Returned lists and rows belong
    to the caller: plain immutable values (the NamedTuples of ``query``;
    for the bulk reads ``raw_rows`` and ``location_samples`` tuples in the
    layout ``query.RawRow`` / ``query.LocationRow`` names), tied to no
    cursor or connection, valid forever, never updated by later writes.
    An unreadable database raises ``errors.Unavailable`` (503).

    Series ids come from ``series``; the sample reads take them. Times in
    ``TimeRange`` are inclusive; a ``RowMask`` (a geo-query's) keeps only
    the samples it lists, everything else (ordering, lastN, limit, offset,
    aggregation) then happens as without it. A ``Prefilter`` is a geo-query's
    test on stored bounding boxes (``geo.filter.box_prefilter``).
    """

    @abstractmethod
    def series(self, scope: Scope, entities: EntityFilter, attrs: Iterable[str] | None = None) -> list[SeriesRef]:
        """``SeriesRef``s of ``scope`` matching ``entities`` and stored attribute
        names (None: all), from the in-memory catalog; may query the database
        to catch up with series created since (another replica's too).

        NGSI-LD: an attribute instance lives in a series. The default
        instance (no datasetId) in the series named after the attribute,
        each other datasetId in its own series named ``attr~datasetId`` (how
        NGSIv2 sees it), with ``ref.dataset_id`` set and ``ref.ld_attr`` the
        NGSI-LD name. Select by ``ref.ld_attr`` (and ``ref.dataset_id`` for
        a ``datasetId`` filter) rather than with ``attrs``, which matches
        stored names. Names are stored as notified or written (no JSON-LD
        expansion). NGSI-LD has no service paths: use ``Scope(tenant)``."""

    @abstractmethod
    def series_names(self, scope: Scope) -> dict[str, dict[str, tuple[str, ...]]]:
        """Entity type → {NGSI-LD attribute name (``ref.ld_attr``): the stored
        names of its series} in ``scope``'s tenant, from the catalog (as
        ``series``). The result is shared: do not change it. Lets a query over
        whole types pick the (type, attribute) series it needs with
        ``series(scope, EntityFilter(types=...), attrs=...)`` instead of
        listing every series of the types."""

    @abstractmethod
    def tenants(self) -> list[str]:
        """Every tenant with at least one series, sorted (catalog, as ``series``)."""

    @abstractmethod
    def sids_with_samples(self, sids: Sequence[int]) -> set[int]:
        """Those of ``sids`` that hold at least one sample."""

    @abstractmethod
    def raw_rows(
        self,
        sids: Sequence[int],
        time: TimeRange,
        *,
        newest_first: bool,
        limit: int,
        offset: int,
        one_per_row: bool,
        attrs_per_row: int = 1,
        mask: RowMask | None = None,
    ) -> list[RawRow]:
        """Samples of the selected rows (one row: one entity notification,
        ``rid``), oldest first. Rows are ordered by time (newest first for
        ``lastN``: ``newest_first``), then ``offset``/``limit`` pick rows of
        the whole result, as QuantumLeap does. ``one_per_row``: each row has
        exactly one selected sample (one attribute); otherwise a row has at
        most ``attrs_per_row``. DuckDB may answer from memory (its tails)."""

    @abstractmethod
    def aggregate(
        self, branches: Sequence[AggBranch], time: TimeRange, agg: Aggregation, mask: RowMask | None = None
    ) -> list[AggregateRow]:
        """Per-series (and per period when ``agg.period``) partial aggregates
        of each branch, including hours retention folded into rollups (never
        under a mask). The caller combines them across series. One statement;
        a backend may answer from memory (its hourly partials, ``storage.partials``)."""

    @abstractmethod
    def latest_index(self, sids: Sequence[int], time: TimeRange, mask: RowMask | None = None) -> list[LatestRow]:
        """Each series' newest sample time in ``time`` (series without one: no row)."""

    @abstractmethod
    def last_values(self, sids: Sequence[int]) -> list[LastValueRow]:
        """Each series' newest sample (by time, then row)."""

    @abstractmethod
    def count(self, sids: Sequence[int], time: TimeRange, mask: RowMask | None = None) -> int:
        """Samples of ``sids`` in ``time``; when there are none (and no mask),
        the rolled-up hours a delete would remove: non-zero whenever a delete
        has something to remove."""

    @abstractmethod
    def latest_geometries(self, sids: Sequence[int], time: TimeRange, prefilter: Prefilter | None) -> list[GeometryRow]:
        """Each series' latest geo sample in ``time`` whose box passes
        ``prefilter``. The latest is chosen first and filtered after, so an
        older position never stands in. DuckDB answers from memory when
        ``time`` is open."""

    @abstractmethod
    def location_extents(self, sids: Collection[int], prefilter: Prefilter | None) -> list[ExtentRow]:
        """Per located series of ``sids`` whose extent (the box of every geo
        sample it ever had) may pass ``prefilter``: the extent and, where the
        backend keeps it, its first position (else None: ``first_locations``).
        Memory only on DuckDB; a table (one query) on PostgreSQL. After a
        delete an extent may be larger than the remaining samples."""

    def located_series(
        self, scope: Scope, types: Sequence[str], attrs: Iterable[str], prefilter: Prefilter | None
    ) -> list[SeriesRef]:
        """The series of the entities of ``types`` (whole tenant) with a
        stored name in ``attrs`` whose extent may pass ``prefilter``, as
        ``location_extents`` decides: where a type-wide geo-query looks."""
        refs = self.series(scope, EntityFilter(types=tuple(types)), attrs)
        near = {row[0] for row in self.location_extents([r.sid for r in refs], prefilter)}
        return [r for r in refs if r.sid in near]

    @abstractmethod
    def first_locations(self, sids: Sequence[int]) -> list[FirstLocationRow]:
        """Each series' first geo sample by (time, row)."""

    @abstractmethod
    def location_samples(self, sids: Sequence[int], time: TimeRange, prefilter: Prefilter | None) -> list[LocationRow]:
        """Every geo sample of ``sids`` in ``time``, plus each series' latest
        one before ``time.start`` (the location its first samples in the
        window had), ordered by (sid, t, rid). Points come as (lon, lat);
        other shapes as GeoJSON, and only where the box passes ``prefilter``
        (the others cannot match, so they are not parsed)."""

    @abstractmethod
    def temporal_instances(
        self,
        sids: Sequence[int],
        window: InstanceWindow | None = None,
        *,
        last_n: int | None = None,
        limit: int | None = None,
        newest_first: bool = False,
    ) -> list[InstanceRow]:
        """NGSI-LD attribute instances of ``sids``, sorted by (sid, time
        property, instance id).

        * ``window``: ``start`` inclusive, ``end`` exclusive (``timerel``
          after / before / between); ``timeproperty`` ``observedAt``
          (default; reads ``coalesce(observed_at, t)`` so instances without
          observedAt, and all NGSIv2 data, have one), ``createdAt``,
          ``modifiedAt``, ``deletedAt`` (those three: only instances that
          have it).
        * ``last_n``: the N newest in the window per series (per attribute
          and datasetId of an entity). ``limit``: at most that many rows in
          all, the oldest (or with ``newest_first``/``last_n`` the newest)
          by the time property; ask for one more than the cap to detect a
          partial answer.
        * value: ``kind`` (``model.Kind``) says which of ``num``/``txt``/
          ``js`` holds it, as in the NGSIv2 reads (INTEGER: ``num`` holds an
          int-valued float; BOOLEAN: ``js`` is ``true``/``false``; GEO:
          ``js`` is the GeoJSON as received; RELATIONSHIP: ``txt`` is the
          object; STRUCTURED: ``js``; NULL: null). ``atype`` is the NGSI-LD
          type as notified (None for an entity-deletion instance and for
          simplified-format data). ``md`` is every other member of the
          instance as received (JSON text): render sub-properties from it,
          times from the columns.
        * ``deleted_at`` set: a deletion instance; its value is
          ``urn:ngsi-ld:null`` (stored as kind NULL).
        * ``model.instance_urn(iid)`` is the ``instanceId``; it never changes
          (compaction and restarts keep ``iid``); ``model.instance_iid``
          reads it back."""

    @abstractmethod
    def instances_matching(self, sids: Sequence[int], window: InstanceWindow, test: ValueTest) -> set[int]:
        """Those of ``sids`` with an instance in ``window`` (its time property
        set and inside; as ``temporal_instances``) that passes ``test``: a
        ``q`` term the database can decide. One statement."""

    @abstractmethod
    def instance_values(self, sids: Sequence[int], window: InstanceWindow) -> list[InstanceValueRow]:
        """The distinct (sid, kind, num, txt, js, md) of the instances in
        ``window`` that have a value (no deletion or null): what a ``q``
        term the database cannot decide is tested on. One statement."""

    @abstractmethod
    def location_instances(
        self, sids: Sequence[int], window: InstanceWindow, prefilter: Prefilter | None
    ) -> list[tuple[int, str]]:
        """The distinct (sid, GeoJSON) of the location instances in
        ``window`` whose stored box passes ``prefilter``: an NGSI-LD
        geo-query's candidates (the caller applies the exact predicate).
        One statement."""

    # True: a read of the instances in a window scans the samples whatever
    # the series (DuckDB), so the geo-query's and ``q``'s reads are best
    # made as one (``window_scan``). False: an index reads each series'
    # rows, so ``q`` is best asked after the geo-query, of the fewer
    # entities it leaves.
    shared_scan = False

    def window_scan(
        self, window: InstanceWindow, locations: LocationProbe | None, tests: Sequence[ValueProbe]
    ) -> WindowScan:
        """``location_instances`` of ``locations`` (sids, prefilter) and
        ``instances_matching`` of each (sids, test), over one window: what
        an NGSI-LD geo-query and ``q`` read. Here one statement each, as an
        index answers each cheaply; a backend that scans for each (DuckDB)
        answers all in one."""
        rows = [] if locations is None else self.location_instances(locations[0], window, locations[1])
        return rows, [self.instances_matching(sids, window, test) for sids, test in tests]

    @abstractmethod
    def instance_aggregate(
        self, sids: Sequence[int], window: InstanceWindow, methods: Sequence[str], periods: InstancePeriods
    ) -> list[InstanceAggregateRow]:
        """Partial aggregates of the instances in ``window`` that have a
        value, per series, period (``periods``), kind, array-ness and
        notified type, in the layout of ``query.InstanceAggregateRow``
        (driver tuples, a fresh list the caller may sort). Only the columns
        ``methods`` (NGSI-LD ``aggrMethods`` names) need are computed.
        Grouped in the database, as one consistent answer: one statement,
        or reads checked against each other (PostgreSQL)."""

    @abstractmethod
    def instance_span(self, sids: Sequence[int], window: InstanceWindow) -> tuple[int, int] | None:
        """The first and last instance times in ``window`` (epoch µs, of
        instances with a value), or None when there is none."""

    @abstractmethod
    def instance_series(self, sids: Sequence[int], iid: int) -> int | None:
        """The one of ``sids`` that holds instance ``iid``, or None."""

    @abstractmethod
    def export_batches(self, sids: Sequence[int], time: TimeRange, batch_rows: int, sort_rows: int) -> SampleBatches:
        """The samples of ``sids`` in ``time`` (inclusive) joined with their
        series' names, oldest first (time, then row, then series), as
        ``storage.export.SampleBatches`` of at most ``batch_rows`` samples in
        the columns ``storage.export.EXPORT_COLUMNS``: what an export writes.

        Memory stays bounded: DuckDB sorts consecutive time windows of about
        ``sort_rows`` samples (memory follows the window), PostgreSQL streams
        a server-side cursor. The query starts here (a failure to start is
        raised here, before any batch); the stream holds a cursor of its own
        (PostgreSQL: a pooled connection and one transaction, one snapshot)
        until ``close()``, which the caller must call (a context manager).
        Use it from one thread at a time, never on the event loop."""

    @abstractmethod
    def sample_counts(self) -> dict[str, int]:
        """Stored samples per tenant (a full scan: for commands, not routes)."""

    @abstractmethod
    def stored_samples(self, batch_rows: int) -> Iterator[list[StoredSample]]:
        """Every stored sample in (row, instance) order, in lists of at most
        ``batch_rows``: what a copy reads. The iterator holds a cursor of its
        own (PostgreSQL: a pooled connection and one transaction, so the
        whole stream is one snapshot) until it is exhausted or closed; use
        it from one thread."""


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
    def close(self) -> None:
        """Drain queued writes, commit them, checkpoint, release the database."""

    async def read(self, fn: Callable[[], T], *, memory_first: bool = True) -> T:
        """``fn()``, awaited: the one way a route reads the store.

        The rule: **no database call on the event loop**. A read runs first
        on the loop with ``storage.memory_only.MEMORY_ONLY`` set, where it
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
        return await read_off_loop(fn, memory_first)


@dataclass(frozen=True, slots=True)
class CopyRun:
    """A copy into a store, as its ``copy_runs`` table records it."""

    source: str
    base_counts: dict[str, int]  # the target's samples per tenant before the copy
    base_rejected: int
    source_samples: int
