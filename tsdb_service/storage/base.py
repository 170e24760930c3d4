"""The storage seam: what routes may ask of a backend.

Modelled on Prometheus' storage interface: writes go through an *appender*
(stage a batch, then commit it atomically), reads through a *querier*. Routes
never see SQL; DuckDB and PostgreSQL each implement both halves.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from datetime import datetime
from typing import Any

from ..model import AttrSample, EntitySample, RejectedNotification
from ..ngsi import ValuesLayout
from .memory_only import T, read_off_loop


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

    ``storage.sql.SqlQuerier`` implements it for SQL backends; row layouts
    are documented there. Thread-safe: routes call it from the threadpool
    (every method may query the database: never call one on the event loop).

    **NGSI-LD temporal reads** (issue 13) use three calls:

    1. ``series(scope, EntityFilter(...), attrs=None)`` → ``SeriesRef``s. An
       NGSI-LD attribute instance lives in a series: the default instance
       (no datasetId) in the series named after the attribute, each other
       datasetId in its own series named ``attr~datasetId`` (how NGSIv2 sees
       it), with ``ref.dataset_id`` set and ``ref.ld_attr`` the NGSI-LD name.
       Select by ``ref.ld_attr`` (and ``ref.dataset_id`` for a ``datasetId``
       filter) rather than with ``attrs=``, which matches stored names.
       Names are stored as notified or written (no JSON-LD expansion).
       NGSI-LD has no service paths: use the whole tenant (``Scope(tenant)``).
    2. ``temporal_instances(sids, InstanceWindow(timeproperty, start, end),
       last_n=None, limit=None, newest_first=False)`` → ``InstanceRow``s
       (``storage.sql``), sorted by (sid, time property, instance id):
       ``sid, iid, at, t, observed_at, created_at, modified_at, deleted_at,
       dataset_id, kind, atype, num, txt, js, md``.
       * window: ``start`` inclusive, ``end`` exclusive (``timerel`` after /
         before / between); ``timeproperty`` ``observedAt`` (default; reads
         ``coalesce(observed_at, t)`` so instances without observedAt, and
         all NGSIv2 data, have one), ``createdAt``, ``modifiedAt``,
         ``deletedAt`` (those three: only instances that have it).
       * ``last_n``: the N newest in the window per series (per attribute
         and datasetId of an entity). ``limit``: at most that many rows in
         all, the oldest (or with ``newest_first``/``last_n`` the newest)
         by the time property; ask for one more than the cap to detect a
         partial answer.
       * value: ``kind`` (``model.Kind``) says which of ``num``/``txt``/
         ``js`` holds it, as in the NGSIv2 reads (INTEGER: ``num`` holds an
         int-valued float; BOOLEAN: ``js`` is ``true``/``false``; GEO: ``js``
         is the GeoJSON as received; RELATIONSHIP: ``txt`` is the object;
         STRUCTURED: ``js``; NULL: null). ``atype`` is the NGSI-LD type as
         notified (``Property``, ``Relationship``, ``GeoProperty``,
         ``LanguageProperty``...; None for an entity-deletion instance and
         for simplified-format data). ``md`` is every other member of the
         instance as received (JSON text: ``observedAt``, ``unitCode``,
         ``datasetId``, nested properties, ``createdAt``...): render
         sub-properties from it, times from the columns.
       * ``deleted_at`` set: a deletion instance; its value is
         ``urn:ngsi-ld:null`` (stored as kind NULL).
       * ``model.instance_urn(iid)`` is the ``instanceId``; it never changes
         (compaction and restarts keep ``iid``); ``model.instance_iid``
         reads it back.
    3. ``instance_series(sids, iid)``: which of ``sids`` holds that instance.
    """

    @abstractmethod
    def series(self, scope, entities, attrs=None) -> list:
        """``SeriesRef``s of ``scope`` matching an ``EntityFilter`` and attribute names."""

    @abstractmethod
    def tenants(self) -> list[str]:
        """Every tenant with at least one series, sorted."""

    @abstractmethod
    def sids_with_samples(self, sids) -> set[int]: ...

    @abstractmethod
    def raw_rows(
        self, sids, time, *, newest_first: bool, limit: int, offset: int, one_per_row: bool, attrs_per_row: int = 1
    ) -> list[tuple]: ...

    @abstractmethod
    def aggregate(self, branches, time, agg) -> list[tuple]: ...

    @abstractmethod
    def latest_index(self, sids, time) -> list[tuple]: ...

    @abstractmethod
    def last_values(self, sids) -> list[tuple]: ...

    @abstractmethod
    def count(self, sids, time) -> int: ...

    @abstractmethod
    def latest_geometries(self, sids, time, prefilter) -> list[tuple]:
        """(sid, GeoJSON) of each series' latest geo sample, box-prefiltered."""

    @abstractmethod
    def temporal_instances(self, sids, window=None, *, last_n=None, limit=None, newest_first=False) -> list:
        """NGSI-LD attribute instances of ``sids``: see the class docstring."""

    @abstractmethod
    def instance_series(self, sids, iid: int) -> int | None:
        """The one of ``sids`` that holds instance ``iid``, or None."""


class Store(ABC):
    """A database with one writer and many readers."""

    backend: str
    # Retention and rollups (storage/retention.py): the background worker,
    # when a policy is set, and whether rollup rows may exist.
    retention = None
    rollup_presence = None

    def stop_retention(self) -> None:
        """Stop the retention worker (its batch in progress finishes first);
        ``close`` calls this before anything else."""
        if self.retention is not None:
            self.retention.stop()

    @abstractmethod
    async def write(self, op: WriteOp) -> None:
        """Queue ``op`` for the group committer; return once it is committed."""

    @abstractmethod
    def write_sync(self, ops: Sequence[WriteOp]) -> None:
        """Commit ops from a non-async caller (bulk loads, copy, tests)."""

    @abstractmethod
    def values_layout(self, tenant: str, subscription_id: str) -> ValuesLayout | None:
        """A registered ``values``-format layout, from memory; a backend
        whose memory may be stale (PostgreSQL: other replicas) reads the
        database first, which ``read`` keeps off the event loop."""

    @abstractmethod
    def layouts(self, tenant: str) -> dict[str, ValuesLayout]: ...

    @abstractmethod
    def rejected(self, tenant: str | None, limit: int, offset: int) -> list[dict[str, Any]]:
        """Rejected notifications of one tenant, newest first; ``None``: every
        tenant (the operator's listing)."""

    def rejected_page(self, tenant: str | None, limit: int, offset: int, max_bytes: int):
        """``rejected`` paged by rendered size too: ``(rows, next offset or
        None)``; at least one row, however big (``storage.rejected.page``)."""
        raise NotImplementedError

    @abstractmethod
    def health(self) -> dict[str, Any]: ...

    def querier(self) -> Querier:
        """The history reader (one per store, thread-safe)."""
        raise NotImplementedError(f"{type(self).__name__} has no history querier yet")

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
