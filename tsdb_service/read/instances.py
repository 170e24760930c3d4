"""NGSI-LD attribute instances: the temporal API's reads.

``TemporalReader.temporal_instances`` documents the rows; the other reads serve the
NGSI-LD query's filters (``q``, geo-queries) and ``aggregatedValues``.
"""

from __future__ import annotations

from typing import Protocol

from tsdb_service.core.query import InstanceAggregateRow, InstanceRow, InstanceValueRow, WindowScan
from tsdb_service.read.requests import (
    InstanceAggregateRead,
    InstanceLocations,
    InstanceLookup,
    InstancePage,
    InstancesIn,
    InstancesMatching,
    InstancesRead,
)
from tsdb_service.read.requests import WindowScan as WindowScanRead


class TemporalReader(Protocol):
    # True: a read of the instances in a window scans the samples whatever
    # the series (DuckDB), so the geo-query's and ``q``'s reads are best
    # made as one (``window_scan``). False: an index reads each series'
    # rows, so ``q`` is best asked after the geo-query, of the fewer
    # entities it leaves.
    shared_scan: bool

    def temporal_instances(self, ask: InstancesRead) -> list[InstanceRow]:
        """NGSI-LD attribute instances, sorted by (sid, time property, instance id).

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
        ...

    def instance_page(self, ask: InstancePage) -> tuple[list[InstanceRow], int | None]:
        """One page of instances by rank (``requests.InstancePage``), rows as
        ``temporal_instances``' (sorted by sid, time property, instance
        id), and the largest instance id among the series' instances in the
        window (``through_iid`` when given; None when no row is on the
        page): what ``through_iid`` keeps the next pages to."""
        ...

    def instances_matching(self, ask: InstancesMatching) -> set[int]:
        """Those of ``ask.sids`` with an instance in the window (its time
        property set and inside) that passes ``ask.test``: a ``q`` term the
        database can decide. One statement."""
        ...

    def instance_values(self, ask: InstancesIn) -> list[InstanceValueRow]:
        """The distinct (sid, kind, num, txt, js, md) of the instances in the
        window that have a value (no deletion or null): what a ``q`` term
        the database cannot decide is tested on. One statement."""
        ...

    def location_instances(self, ask: InstanceLocations) -> list[tuple[int, str]]:
        """The distinct (sid, GeoJSON) of the location instances in the window
        whose stored box passes the prefilter: an NGSI-LD geo-query's
        candidates (the caller applies the exact predicate). One statement."""
        ...

    def window_scan(self, ask: WindowScanRead) -> WindowScan:
        """``location_instances`` of ``ask.locations`` and ``instances_matching``
        of each of ``ask.tests``, over one window: what an NGSI-LD geo-query
        and ``q`` read, in one scan where the backend scans anyway."""
        ...

    def instance_aggregate(self, ask: InstanceAggregateRead) -> list[InstanceAggregateRow]:
        """Partial aggregates of the instances in the window that have a
        value, per series, period, kind, array-ness and notified type, in
        the layout of ``query.InstanceAggregateRow`` (a fresh list the
        caller may sort). Only the columns the methods need are computed.
        Grouped in the database, as one consistent answer: one statement,
        or reads checked against each other (PostgreSQL)."""
        ...

    def instance_span(self, ask: InstancesIn) -> tuple[int, int] | None:
        """The first and last instance times in the window (epoch µs, of
        instances with a value), or None when there is none."""
        ...

    def instance_at(self, ask: InstanceLookup) -> tuple[int, int] | None:
        """(sid, iid) of the instance of ``ask.sids`` that ``ask.instance_id``
        names, or None: the instance ``model.instance_iid`` reads from it,
        or the one whose client-given ``instanceId`` (a member of ``md``) it is."""
        ...


class SeparateScans:
    """``window_scan`` as one read per probe: for a backend whose index
    answers each cheaply (``shared_scan`` False)."""

    shared_scan = False

    def window_scan(self: _Probes, ask: WindowScanRead) -> WindowScan:
        rows = []
        if ask.locations is not None:
            sids, prefilter = ask.locations
            rows = self.location_instances(InstanceLocations(sids, ask.window, prefilter))
        return rows, [self.instances_matching(InstancesMatching(sids, ask.window, test)) for sids, test in ask.tests]


class _Probes(Protocol):
    def location_instances(self, ask: InstanceLocations) -> list[tuple[int, str]]: ...

    def instance_page(self, ask: InstancePage) -> tuple[list[InstanceRow], int | None]:
        """One page of instances by rank (``requests.InstancePage``), rows as
        ``temporal_instances``' (sorted by sid, time property, instance
        id), and the largest instance id among the series' instances in the
        window (``through_iid`` when given; None when no row is on the
        page): what ``through_iid`` keeps the next pages to."""
        ...

    def instances_matching(self, ask: InstancesMatching) -> set[int]: ...
