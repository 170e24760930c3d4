"""What a read asks of the store: one frozen request object per call.

Each querier method (``read.catalogue``, ``read.samples``, ``read.locations``,
``read.instances``, ``read.bulk``) takes one of these, built by the layer
that parsed the HTTP request (``history``, the faces), so a backend sees
every option of a read in one value and no signature is written twice.
Times in a ``TimeRange`` are inclusive; a ``RowMask`` (a geo-query's) keeps
only the samples it lists; a ``Prefilter`` is a geo-query's test on stored
bounding boxes (``geo.filter.box_prefilter``).
"""

from __future__ import annotations

from collections.abc import Collection, Sequence
from dataclasses import dataclass
from datetime import datetime

from tsdb_service.core.query import (
    AggBranch,
    Aggregation,
    EntityFilter,
    InstancePeriods,
    InstanceWindow,
    LocationProbe,
    Prefilter,
    RowMask,
    Scope,
    TimeRange,
    ValueProbe,
    ValueTest,
)

ANY_TIME = InstanceWindow()  # every instance, by observedAt


@dataclass(frozen=True, slots=True)
class SeriesSelect:
    """Series of ``scope`` matching ``entities`` and, unless None, whose
    stored attribute name is one of ``attrs``."""

    scope: Scope
    entities: EntityFilter
    attrs: Collection[str] | None = None


@dataclass(frozen=True, slots=True)
class RowsRead:
    """The samples of the selected rows (one row: one entity notification).

    Rows are ordered by time (newest first for lastN: ``newest_first``), then
    ``offset``/``limit`` pick rows of the whole result, as QuantumLeap does.
    ``one_per_row``: each row has exactly one selected sample (one
    attribute); otherwise a row has at most ``attrs_per_row``."""

    sids: Sequence[int]
    time: TimeRange
    newest_first: bool
    limit: int
    offset: int
    one_per_row: bool
    attrs_per_row: int = 1
    mask: RowMask | None = None


@dataclass(frozen=True, slots=True)
class AggregateRead:
    """Per-series (and per period when ``agg.period``) partial aggregates of
    each branch over ``time``."""

    branches: Sequence[AggBranch]
    time: TimeRange
    agg: Aggregation
    mask: RowMask | None = None


@dataclass(frozen=True, slots=True)
class SamplesIn:
    """The samples of ``sids`` in ``time`` (under ``mask``, if any)."""

    sids: Sequence[int]
    time: TimeRange
    mask: RowMask | None = None


@dataclass(frozen=True, slots=True)
class LocationsIn:
    """The geo samples of ``sids`` in ``time`` whose box passes ``prefilter``."""

    sids: Sequence[int]
    time: TimeRange
    prefilter: Prefilter | None = None


@dataclass(frozen=True, slots=True)
class ExtentsNear:
    """The extents of the located series among ``sids`` that may pass ``prefilter``."""

    sids: Collection[int]
    prefilter: Prefilter | None = None


@dataclass(frozen=True, slots=True)
class LocatedSelect:
    """The series of the entities of ``types`` with a stored name in
    ``attrs`` whose extent may pass ``prefilter``."""

    scope: Scope
    types: Sequence[str]
    attrs: Collection[str]
    prefilter: Prefilter | None = None


@dataclass(frozen=True, slots=True)
class InstancesRead:
    """NGSI-LD attribute instances of ``sids`` in ``window``: all of them, the
    ``last_n`` newest per series, or at most ``limit`` in all."""

    sids: Sequence[int]
    window: InstanceWindow = ANY_TIME
    last_n: int | None = None
    limit: int | None = None
    newest_first: bool = False


@dataclass(frozen=True, slots=True)
class InstancePage:
    """One page of each series' instances in ``window`` by rank (ETSI TS
    104 176 clause 6.4.7.3): each series' instances ordered by time property
    then instance id (``ascending``, as ``firstN``; else newest first, as
    ``lastN``), those ranked after ``offset`` and at most ``size`` more
    (None: all), taken rank by rank across the series (every series' first,
    then every series' second...) up to ``limit`` rows in all. With
    ``through_iid`` only the instances whose instance id is at most that:
    the instances stored when a walk through the pages began (ids grow as
    instances are stored), so a walk's ranks stay put while more arrive."""

    sids: Sequence[int]
    window: InstanceWindow
    ascending: bool
    offset: int
    size: int | None
    limit: int
    through_iid: int | None = None


@dataclass(frozen=True, slots=True)
class ValuesAt:
    """Each series' newest sample at or before ``at`` (by time, then row)."""

    sids: Sequence[int]
    at: datetime


@dataclass(frozen=True, slots=True)
class InstancesIn:
    """The instances of ``sids`` in ``window``."""

    sids: Sequence[int]
    window: InstanceWindow


@dataclass(frozen=True, slots=True)
class InstancesMatching:
    """The series among ``sids`` with an instance in ``window`` that passes ``test``."""

    sids: Sequence[int]
    window: InstanceWindow
    test: ValueTest


@dataclass(frozen=True, slots=True)
class InstanceLocations:
    """The location instances of ``sids`` in ``window`` whose box passes ``prefilter``."""

    sids: Sequence[int]
    window: InstanceWindow
    prefilter: Prefilter | None = None


@dataclass(frozen=True, slots=True)
class WindowScan:
    """A geo-query's locations (sids, prefilter) and the ``q`` tests (sids,
    test) of one NGSI-LD query, over one window."""

    window: InstanceWindow
    locations: LocationProbe | None
    tests: Sequence[ValueProbe]


@dataclass(frozen=True, slots=True)
class InstanceAggregateRead:
    """Partial aggregates of ``sids``' instances in ``window`` per period:
    only the columns the NGSI-LD ``aggrMethods`` in ``methods`` need."""

    sids: Sequence[int]
    window: InstanceWindow
    methods: Sequence[str]
    periods: InstancePeriods


@dataclass(frozen=True, slots=True)
class InstanceLookup:
    """Which of ``sids`` holds the instance an ``instanceId`` names: one of
    ours (``model.instance_urn``) or one a client gave (kept in ``md``)."""

    sids: Sequence[int]
    instance_id: str


@dataclass(frozen=True, slots=True)
class ExportRead:
    """The samples of ``sids`` in ``time``, joined with their series' names,
    in batches of at most ``batch_rows``, sorted ``sort_rows`` at a time."""

    sids: Sequence[int]
    time: TimeRange
    batch_rows: int
    sort_rows: int
