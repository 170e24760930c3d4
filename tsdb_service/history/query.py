"""What a history request asks for, parsed and validated, before any SQL.

Routes turn HTTP into these frozen values (``history.params``); storage
renders them to SQL (``storage.sql``); ``history.shape`` turns the rows back
into QuantumLeap's JSON. Nothing here knows about HTTP or a database.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from datetime import datetime
from enum import Enum
from typing import Any


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
        for path in self.service_paths:
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
    """``POST /v2/op/query``: the latest value of each attribute per entity."""

    scope: Scope
    selectors: tuple[EntityFilter, ...]
    attrs: tuple[ValuePath, ...] | None = None


@dataclass(frozen=True, slots=True)
class DeleteQuery:
    """``DELETE /v2/entities/{id}`` and ``DELETE /v2/types/{type}``."""

    scope: Scope
    entities: EntityFilter
    time: TimeRange = field(default_factory=TimeRange)
