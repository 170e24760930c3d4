"""The query vocabulary: what a read asks for, parsed and validated, before any SQL.

Both sides of the read seam speak it. Request parsers (``faces.quantumleap.params``,
``grafana.params``, ``ngsild.params``) turn HTTP into these frozen values;
storage backends render them to SQL (``storage.sql``); ``faces.quantumleap.shape``,
``grafana`` and ``ngsild.render`` turn the rows back into JSON. Nothing here
knows about HTTP or a database, so neither side imports the other.
"""

from __future__ import annotations

import bisect
from collections.abc import Sequence
from dataclasses import dataclass, field
from datetime import datetime, timedelta
from enum import Enum
from typing import Any, NamedTuple, Protocol

from tsdb_service.core.model import ld_attr_name


class AggrMethod(str, Enum):
    COUNT = "count"
    SUM = "sum"
    AVG = "avg"
    MIN = "min"
    MAX = "max"


class AggrPeriod(str, Enum):
    YEAR = "year"
    MONTH = "month"
    DAY = "day"
    HOUR = "hour"
    MINUTE = "minute"
    SECOND = "second"


class AggrScope(str, Enum):
    ENTITY = "entity"  # one aggregate per entity (QuantumLeap's only scope)
    GLOBAL = "global"  # one aggregate across every matched entity


@dataclass(frozen=True, slots=True)
class ValuePath:
    """An attribute, or a place inside a structured attribute's value.

    ``odom(twist.twist.linear.x)`` is ``ValuePath("odom", ("twist", "twist",
    "linear", "x"))``; a plain ``temperature`` has no steps. Steps are object
    keys (str) or array indices (int). ``text`` is how responses name it.
    """

    attr: str
    steps: tuple[str | int, ...] = ()

    @property
    def text(self) -> str:
        if not self.steps:
            return self.attr
        out = []
        for step in self.steps:
            if isinstance(step, int):
                out.append(f"[{step}]")
            else:
                out.append(f".{step}" if out else step)
        return f"{self.attr}({''.join(out)})"

    def __str__(self) -> str:
        return self.text


@dataclass(frozen=True, slots=True)
class Aggregation:
    method: AggrMethod
    period: AggrPeriod | None = None
    scope: AggrScope = AggrScope.ENTITY


@dataclass(frozen=True, slots=True)
class Scope:
    """Which series a request may see: always one tenant, some service paths.

    ``service_paths`` are normalised query paths; ``("/",)`` is the whole
    tenant. A path matches itself and its descendants, anchored and
    case-sensitive.
    """

    tenant: str
    service_paths: tuple[str, ...] = ("/",)

    @property
    def whole_tenant(self) -> bool:
        return "/" in self.service_paths

    def matches(self, service_path: str) -> bool:
        if "/" in self.service_paths:
            return True
        for path in self.service_paths:  # noqa: SIM110 - a plain loop beats any() on this per-series path
            if service_path == path or service_path.startswith(path + "/"):
                return True
        return False


@dataclass(frozen=True, slots=True)
class EntityFilter:
    """Which entities: ids (exact), an id regex, types. ``None`` = any."""

    ids: tuple[str, ...] | None = None
    id_pattern: str | None = None
    types: tuple[str, ...] | None = None


@dataclass(frozen=True, slots=True)
class TimeRange:
    """Inclusive bounds, timezone-aware UTC; ``None`` = open."""

    start: datetime | None = None
    end: datetime | None = None

    @property
    def open(self) -> bool:
        return self.start is None and self.end is None


class Shape(str, Enum):
    """The response layouts, named after QuantumLeap's handlers."""

    ENTITY_ATTR = "1T1E1A"  # /v2/entities/{id}/attrs/{attr}
    ENTITY = "1T1ENA"  # /v2/entities/{id}
    TYPE_ATTR = "1TNE1A"  # /v2/types/{type}/attrs/{attr}
    TYPE = "1TNENA"  # /v2/types/{type}
    ATTR = "NTNE1A"  # /v2/attrs/{attr}
    ATTRS = "NTNENA"  # /v2/attrs


@dataclass(frozen=True, slots=True)
class HistoryQuery:
    """One history request on any of the six history endpoints.

    ``attrs`` is ``None`` for "every attribute". ``limit`` is already capped
    at the configured maximum. ``geo`` is the hook for geographical queries
    (a ``tsdb_service.geo`` filter); ``None`` = no geo filter.
    """

    shape: Shape
    scope: Scope
    entities: EntityFilter = field(default_factory=EntityFilter)
    attrs: tuple[ValuePath, ...] | None = None
    time: TimeRange = field(default_factory=TimeRange)
    last_n: int | None = None
    limit: int = 10_000
    offset: int = 0
    aggregation: Aggregation | None = None
    values_only: bool = False  # the /value variant
    geo: Any = None


@dataclass(frozen=True, slots=True)
class EntityListQuery:
    """``GET /v2/entities``: ids with their type and latest time index."""

    scope: Scope
    entities: EntityFilter = field(default_factory=EntityFilter)
    time: TimeRange = field(default_factory=TimeRange)
    limit: int = 10_000
    offset: int = 0
    geo: Any = None  # a tsdb_service.geo.filter.GeoFilter


@dataclass(frozen=True, slots=True)
class LastValueQuery:
    """``POST /v2/op/query``: the latest value of each attribute per entity,
    or with ``as_of`` (our extension) the latest at or before that instant."""

    scope: Scope
    selectors: tuple[EntityFilter, ...]
    attrs: tuple[ValuePath, ...] | None = None
    as_of: datetime | None = None


@dataclass(frozen=True, slots=True)
class DeleteQuery:
    """``DELETE /v2/entities/{id}`` and ``DELETE /v2/types/{type}``."""

    scope: Scope
    entities: EntityFilter
    time: TimeRange = field(default_factory=TimeRange)


# -- what the read seam (``read.Querier``) takes and returns ---------

_EPOCH = datetime(1970, 1, 1)

# NGSI-LD time properties an ``InstanceWindow`` can select on.
TIME_PROPERTIES = ("observedAt", "createdAt", "modifiedAt", "deletedAt")


@dataclass(frozen=True, slots=True)
class SeriesRef:
    sid: int
    service_path: str
    entity_id: str
    entity_type: str
    attr: str  # the stored name: attr~datasetId for a non-default NGSI-LD datasetId
    dataset_id: str | None = None  # NGSI-LD datasetId; None: the default instance

    @property
    def ld_attr(self) -> str:
        """The NGSI-LD attribute name (without the datasetId suffix)."""
        return ld_attr_name(self.attr, self.dataset_id)


@dataclass(frozen=True, slots=True)
class AggBranch:
    """One aggregated column family: plain attributes (``steps`` empty) or a
    value path into structured values, over the given series."""

    sids: tuple[int, ...]
    steps: tuple[str | int, ...] = ()


class RowMask:
    """Which samples of some series a read keeps: per series, half-open
    intervals of (time, row id), ``[(t0, r0), (t1, r1))``, an open end where
    ``t1`` is None. Times are epoch microseconds. A geo-query becomes one:
    the intervals in which an entity's location matched, repeated for each
    of its series, so a sample is kept when its row's location matched. A
    series not listed keeps nothing."""

    __slots__ = ("intervals",)

    def __init__(self, intervals: dict[int, list[tuple[int, int, int | None, int | None]]]):
        self.intervals = intervals

    def arrays(self) -> list[list]:
        """The five parallel arrays ``Dialect.mask_relation`` binds."""
        sids, t0, r0, t1, r1 = [], [], [], [], []
        for sid, spans in self.intervals.items():
            for a, ra, b, rb in spans:
                sids.append(sid)
                t0.append(_moment(a))
                r0.append(ra)
                t1.append(None if b is None else _moment(b))
                r1.append(rb)
        return [sids, t0, r0, t1, r1]

    def keep(self, sid: int, rows: list[tuple]) -> list[tuple]:
        """Those of ``rows`` (sorted by (t µs, rid, ...)) the mask keeps."""
        out: list[tuple] = []
        for a, ra, b, rb in self.intervals.get(sid, ()):
            lo = bisect.bisect_left(rows, (a, ra))
            hi = len(rows) if b is None else bisect.bisect_left(rows, (b, rb))
            out.extend(rows[lo:hi])
        return out


def _moment(micros: int) -> datetime:
    return _EPOCH + timedelta(microseconds=micros)


@dataclass(frozen=True, slots=True)
class InstanceWindow:
    """Which instances a temporal query selects: those whose ``timeproperty``
    lies in [start, end) (either bound optional; NGSI-LD's ``timerel``:
    ``after`` = start only, ``before`` = end only, ``between`` = both).
    Times are timezone-aware.

    ``spans`` narrows some series further: ``(sid, start, end)``, a listed
    series keeps only its instances whose time property lies in one of its
    spans [start, end) (either bound None: open); a series not listed keeps
    every instance of the window. An entity's ``scopeQ`` matches during
    spans of time (its scope changes), which bound its instances."""

    timeproperty: str = "observedAt"  # one of TIME_PROPERTIES
    start: datetime | None = None
    end: datetime | None = None
    spans: tuple[tuple[int, datetime | None, datetime | None], ...] = ()

    def __post_init__(self) -> None:
        if self.timeproperty not in TIME_PROPERTIES:
            raise ValueError(f"unknown time property {self.timeproperty!r}")


class InstanceRow(NamedTuple):
    """One NGSI-LD attribute instance. Times are naive UTC datetimes."""

    sid: int
    iid: int  # model.instance_urn(iid) is its instanceId
    at: datetime  # the window's time property (observedAt: coalesce(observed_at, t))
    t: datetime  # the NGSIv2 row time (time index)
    observed_at: datetime | None  # as sent; None: the instance had no observedAt
    created_at: datetime | None
    modified_at: datetime | None
    deleted_at: datetime | None  # set: a deletion instance (value urn:ngsi-ld:null)
    dataset_id: str | None  # from the series; None: the default instance
    kind: int  # model.Kind
    atype: str | None  # Property, GeoProperty, Relationship, ... as notified
    num: float | None
    txt: str | None
    js: str | None
    md: str | None  # sub-properties as JSON text, exactly as received


# -- rows the read seam returns ----------------------------------------------
#
# NamedTuples: still tuples (callers unpack them positionally; the SQL
# backends build them from the driver's tuples with one C-level call per
# row, ``tuple.__new__(Row, row)``), with names for everyone else. The two
# bulk reads, ``raw_rows`` (lastN=1000: a thousand rows) and
# ``location_samples`` (every position in a window), return the driver's
# tuples as they are, typed by layout: a NamedTuple costs ~0.1 µs a row to
# build, 7 % of a type-level lastN=1000 (benchmarks/reads_cpu.py). Times are
# ISO 8601 text (``YYYY-MM-DDTHH:MM:SS.mmm+00:00``) where a route renders
# them as they are, epoch microseconds (``_us``) where code compares them.

# One sample of a history read (``Querier.raw_rows``): (sid, rid (the row:
# one entity in one notification), ISO time, kind (``model.Kind``: which of
# num / txt / js holds the value), num, txt, js).
RawRow = tuple[int, int, str, int, float | None, str | None, str | None]


class AggregateRow(NamedTuple):
    """One series' (and period's) partial aggregate (``Querier.aggregate``)."""

    branch: int  # index into the request's AggBranch list
    sid: int
    bucket: str | None  # the period's start (ISO 8601); None without a period
    n_present: int  # samples with a value (not NULL)
    n_numeric: int  # of those, numbers
    value: float | None  # sum (sum, avg), min or max of the numbers; None for count
    all_integer: bool | None  # every number an integer; None when there is none


class LatestRow(NamedTuple):
    """A series' newest sample time (``Querier.latest_index``)."""

    sid: int
    time: str  # ISO 8601


class LastValueRow(NamedTuple):
    """A series' newest sample (``Querier.last_values``)."""

    sid: int
    time: str  # ISO 8601
    kind: int
    atype: str | None  # the NGSI type as notified
    num: float | None
    txt: str | None
    js: str | None


class GeometryRow(NamedTuple):
    """A series' latest location (``Querier.latest_geometries``)."""

    sid: int
    geojson: str  # normalised GeoJSON text


# One geo sample over time (``Querier.location_samples``): (sid, t µs, rid,
# its box passes the prefilter, it is a point, lon and lat (its box's
# min_lon/min_lat: a point's position), GeoJSON (only for a shape, not a
# point, whose box passes; else None)).
LocationRow = tuple[int, int, int, bool, bool, float, float, str | None]


class ExtentRow(NamedTuple):
    """Where a series has ever been (``Querier.location_extents``)."""

    sid: int
    min_lon: float
    min_lat: float
    max_lon: float
    max_lat: float
    first_t_us: int | None  # its first geo sample, where the backend keeps it
    first_rid: int | None


class FirstLocationRow(NamedTuple):
    """A series' first geo sample by (time, row) (``Querier.first_locations``)."""

    sid: int
    t_us: int
    rid: int


class StoredSample(NamedTuple):
    """One stored sample with everything a copy needs (``Querier.stored_samples``);
    times are naive UTC datetimes. Instance ids stay behind: an instanceId
    names an instance in one store."""

    rid: int
    sid: int
    t: datetime
    kind: int
    atype: str | None
    num: float | None
    txt: str | None
    js: str | None
    geo: str | None
    lon: float | None
    lat: float | None
    min_lon: float | None
    min_lat: float | None
    max_lon: float | None
    max_lat: float | None
    md: str | None
    observed_at: datetime | None
    created_at: datetime | None
    modified_at: datetime | None
    deleted_at: datetime | None


class Bounds(Protocol):
    """A lon/lat box (``geo.filter.BBox`` is one)."""

    @property
    def min_lon(self) -> float: ...
    @property
    def min_lat(self) -> float: ...
    @property
    def max_lon(self) -> float: ...
    @property
    def max_lat(self) -> float: ...


# What a stored bounding box must do to possibly match a geo-query
# (``geo.filter.box_prefilter``): ("intersects", box), overlap ``box``;
# ("within", box), lie inside it. None: no prefilter.
Prefilter = tuple[str, Bounds]


# -- the bounding-box prefilter ----------------------------------------------------------------
#
# A stored sample keeps its geometry's box (min_lon, min_lat, max_lon,
# max_lat). A geo-query's ``Prefilter`` says what that box must do to
# possibly match: "within" lie inside the query box, "intersects" overlap
# it. The same two tests run in SQL (``storage.sql.dialect.box_sql``) and in memory
# (``box_passes``: DuckDB's latest locations and extents, the in-memory querier).

WITHIN = "within"
Box = tuple[float, float, float, float]  # min_lon, min_lat, max_lon, max_lat


def box_passes(how: str, b: Box, box: Bounds) -> bool:
    if how == WITHIN:
        return b[0] >= box.min_lon and b[2] <= box.max_lon and b[1] >= box.min_lat and b[3] <= box.max_lat
    return b[2] >= box.min_lon and b[0] <= box.max_lon and b[3] >= box.min_lat and b[1] <= box.max_lat


def extent_prefilter(prefilter: Prefilter | None) -> Prefilter | None:
    """The test on a series' extent (the box of all its samples' boxes): a
    sample's box passes either test only if it overlaps the query box, and
    the extent holds every sample's box, so overlap is the extent's test."""
    return None if prefilter is None else ("intersects", prefilter[1])


# -- NGSI-LD temporal reads: what ``ngsild`` asks beyond whole instances ----------


@dataclass(frozen=True, slots=True)
class ValueTest:
    """A test on an instance's plain value that the database can make (a
    ``q`` term without sub-property or value path, ``ngsild.fetch``).
    ``op`` None: the instance has a value (it is no deletion or null);
    ``ANY_INSTANCE``: any instance, deletions too (is there one in the
    window?); ``ARRAY_INSTANCE``: an instance whose value is a JSON array
    (whose elements a ``q`` term tests one by one, in Python); otherwise
    ``value`` compared by ``op`` (``==``, ``>``, ``>=``, ``<``, ``<=``): a
    float against number instances (Number, Integer), a str (``==`` only)
    against text and relationship instances."""

    op: str | None = None
    value: float | str | None = None

    def __post_init__(self) -> None:
        if self.op is None or self.op in (ANY_INSTANCE, ARRAY_INSTANCE):
            return
        if isinstance(self.value, str) and self.op != "==":
            raise ValueError("a text test compares with == only")
        if self.op not in VALUE_TEST_OPS or not isinstance(self.value, (float, str)):
            raise ValueError(f"not a value test: {self.op!r} {self.value!r}")


VALUE_TEST_OPS = ("==", ">", ">=", "<", "<=")
ANY_INSTANCE = "any"  # ``ValueTest.op``: any instance passes
ARRAY_INSTANCE = "array"  # ``ValueTest.op``: an instance whose value is a JSON array passes

# An instance's value as ``Querier.instance_values`` reads it: (sid, kind,
# num, txt, js, md), distinct; the columns as in ``InstanceRow``.
InstanceValueRow = tuple[int, int, float | None, str | None, str | None, str | None]

# What ``Querier.window_scan`` is asked: the location series and the box
# their instances' boxes must pass; per ``q`` term, the series and the test.
# It answers the distinct (sid, GeoJSON) locations and, per test, the
# series with an instance that passed.
LocationProbe = tuple[Sequence[int], Prefilter | None]
ValueProbe = tuple[Sequence[int], ValueTest]
WindowScan = tuple[list[tuple[int, str]], list[set[int]]]


@dataclass(frozen=True, slots=True)
class InstancePeriods:
    """How ``Querier.instance_aggregate`` groups instances into periods
    (bounds as epoch microseconds, a period is [start, end)):

    * nothing set: one period (bucket 0);
    * ``step_us``: periods of that length from ``origin_us``, or, when it is
      None, from the first instance in the window (found by the backend);
    * ``edges``: the consecutive periods [edges[i], edges[i + 1]) (calendar
      periods, laid out by the caller); a bucket is its period's start."""

    step_us: int | None = None
    origin_us: int | None = None
    edges: tuple[int, ...] = ()


# A row of ``Querier.instance_aggregate`` (driver tuples, indexed by
# position: ``ngsild.aggregate`` merges them; few rows, so no names): one
# per (series, period, kind, is-array, notified type): (sid, bucket (the
# period's start in epoch µs, 0 for one period), kind, is_array (1: a JSON
# array, its size is x), atype, n (instances with a value), n_distinct,
# nx (instances with a number x), sum(x), sum(x * x), min(x), max(x),
# min(txt), max(txt), the first and last instance times (epoch µs)). A
# column no asked method needs is None, and so is the first instance time
# unless the whole window is one period (its start when the window has none).
InstanceAggregateRow = tuple[
    int, int, int, int, str | None, int | None, int | None, int | None, Any, Any, Any, Any, Any, Any, int | None, int
]
