"""What a temporal request asks for, parsed and validated, before any SQL.

``ngsild.params`` builds a ``TemporalQuery`` from HTTP (query string or a
``Query`` body); ``ngsild.fetch`` runs it against the store;
``ngsild.render`` turns the instances into NGSI-LD JSON. Attribute and type
names in here are already expanded to IRIs with the request's @context.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from datetime import datetime
from enum import Enum
from typing import Any

from tsdb_service.faces.ngsild import boolexpr
from tsdb_service.faces.ngsild.qlang import Node
from tsdb_service.faces.ngsild.scope import ScopeExpr

DEFAULT_DATASET = "@none"  # how a request names the default instance in datasetId


class TimeProperty(str, Enum):
    OBSERVED_AT = "observedAt"
    CREATED_AT = "createdAt"
    MODIFIED_AT = "modifiedAt"
    DELETED_AT = "deletedAt"


class Format(str, Enum):
    NORMALIZED = "normalized"
    TEMPORAL_VALUES = "temporalValues"  # the simplified temporal representation
    AGGREGATED = "aggregatedValues"
    CONCISE = "concise"  # normalized, without the types the value members say


AGGR_METHODS = ("totalCount", "distinctCount", "sum", "avg", "min", "max", "stddev", "sumsq")


@dataclass(frozen=True, slots=True)
class Window:
    """The temporal query as a half-open interval ``[start, end)`` on one
    time property: ``before`` → ``(-inf, timeAt)``, ``after`` →
    ``[timeAt, +inf)``, ``between`` → ``[timeAt, endTimeAt)``; no
    ``timerel``: all of time. Bounds are timezone-aware UTC."""

    timerel: str | None = None
    start: datetime | None = None
    end: datetime | None = None
    timeproperty: TimeProperty = TimeProperty.OBSERVED_AT
    # (sid, start, end): series narrowed to spans of time (``InstanceWindow.spans``), from ``scopeQ``
    spans: tuple[tuple[int, datetime | None, datetime | None], ...] = ()


@dataclass(frozen=True, slots=True)
class Duration:
    """An ISO 8601 duration ``PnYnMnDTnHnMnS`` or ``PnW``. Calendar parts
    (years, months) are kept apart because their length varies."""

    months: int = 0  # years x 12 + months
    days: int = 0  # weeks x 7 + days
    micros: int = 0  # hours, minutes, seconds

    @property
    def zero(self) -> bool:
        return self.months == 0 and self.days == 0 and self.micros == 0

    @property
    def calendar(self) -> bool:
        return self.months != 0

    @property
    def fixed_micros(self) -> int:
        """The length of a duration without calendar parts, in microseconds."""
        return self.days * 86_400_000_000 + self.micros


@dataclass(frozen=True, slots=True)
class Aggregation:
    methods: tuple[str, ...]
    period: Duration  # zero: one period over the whole window


@dataclass(frozen=True, slots=True)
class TypeName:
    iri: str
    term: str = ""  # as the request wrote it (stored names may be that term)


TypeAnd = boolexpr.All  # every part
TypeOr = boolexpr.AnyOf  # one part
TypeExpr = TypeName | boolexpr.All | boolexpr.AnyOf


def type_matches(expr: TypeExpr, has: Callable[[TypeName], bool]) -> bool:
    """Does an entity satisfy ``expr``? ``has(name)`` says whether it has one type."""
    return boolexpr.holds(expr, has)


def type_names(expr: TypeExpr) -> list[TypeName]:
    return boolexpr.leaves(expr)


@dataclass(frozen=True, slots=True)
class Selector:
    """One entity selector: ids (exact), an id regex, a type expression;
    ``None`` = any. A query's selectors are alternatives (OR)."""

    ids: tuple[str, ...] | None = None
    id_pattern: str | None = None
    types: TypeExpr | None = None


@dataclass(frozen=True)
class GeoQuery:
    """``georel``/``geometry``/``coordinates``/``geoproperty``; ``filter``
    is a ``tsdb_service.geo.filter.GeoFilter`` (lon/lat shapes, geodesic
    distances)."""

    filter: Any
    geoproperty: str  # expanded IRI


@dataclass(frozen=True)
class TemporalQuery:
    """One temporal read. ``attrs``/``pick``/``omit`` hold expanded IRIs
    (and ``id``/``type`` in pick/omit); ``None`` means not given.
    ``entity_id`` is set on ``GET /temporal/entities/{id}``."""

    tenant: str
    window: Window = Window()
    entity_id: str | None = None
    selectors: tuple[Selector, ...] = (Selector(),)
    attrs: tuple[str, ...] | None = None
    pick: tuple[str, ...] | None = None
    omit: tuple[str, ...] | None = None
    q: Node | None = None
    scope_q: ScopeExpr | None = None
    geo: GeoQuery | None = None
    dataset_ids: tuple[str, ...] | None = None
    last_n: int | None = None
    first_n: int | None = None  # TS 104 176: the oldest N per attribute
    offset_n: int | None = None  # TS 104 176: skip N instances per attribute (firstN/lastN order)
    stored_through: int | None = None  # our links: the instances stored when a walk through pages began
    as_of: datetime | None = None  # our extension: each attribute's latest instance at or before it
    format: Format = Format.NORMALIZED
    aggregation: Aggregation | None = None
    sys_attrs: bool = False
    lang: tuple[tuple[str, float], ...] | None = None  # language ranges, best first (lowercase)
    limit: int = 20
    offset: int = 0
    count: bool = False
    descending: bool = False  # orderBy=id;desc
    local: bool = False

    @property
    def paged_by_rank(self) -> bool:
        """Does the request use TS 104 176's temporal pagination (clause
        6.4.7.3: ``firstN`` or ``offsetN``, or a link of ours that continues
        one)? Then every answer is 200 with ``Link`` intervals; otherwise
        V1.9.1's (clause 6.3.10): 206 and ``Content-Range`` past the cap."""
        return self.first_n is not None or self.offset_n is not None or self.stored_through is not None

    @property
    def wanted_attrs(self) -> tuple[str, ...] | None:
        """The attributes to return: ``attrs`` narrowed by ``pick``; ``omit``
        is applied by the caller."""
        if self.pick is not None:
            picked = tuple(a for a in self.pick if a not in ("id", "type"))
            if self.attrs is not None:
                return tuple(a for a in picked if a in self.attrs)
            return picked
        return self.attrs
