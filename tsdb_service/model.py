"""The ingest data model: what a parsed notification becomes before storage.

The parser (``tsdb_service.ngsi``) produces these; every storage backend
consumes them. They carry no SQL and no HTTP, so both sides can be tested on
their own.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from datetime import datetime
from enum import IntEnum


class Kind(IntEnum):
    """How a sample's value is stored. Stored per sample, not per attribute,
    so an attribute may change type between notifications (QuantumLeap #778).

    The numeric codes are persisted: never renumber them.
    """

    NULL = 0
    NUMBER = 1  # float, kept in ``num``
    INTEGER = 2  # int, kept in ``num`` and rendered back as int
    BOOLEAN = 3  # kept in ``num`` as 0/1 and ``js`` as true/false
    TEXT = 4  # kept in ``txt``
    DATETIME = 5  # ISO text in ``txt``; epoch seconds in ``num``
    STRUCTURED = 6  # objects and arrays: JSON text in ``js``
    GEO = 7  # raw value as JSON in ``js``; normalised GeoJSON in ``geo``
    RELATIONSHIP = 8  # target entity id in ``txt``

    @property
    def numeric(self) -> bool:
        """Whether sum/avg/min/max are meaningful for this kind."""
        return self in (Kind.NUMBER, Kind.INTEGER)


@dataclass(frozen=True, slots=True)
class Geometry:
    """A location normalised to GeoJSON (lon, lat order) with a bounding box,
    so SQL can prefilter by box before shapely applies the exact predicate."""

    geojson: str
    lon: float  # representative point (centroid for areas)
    lat: float
    min_lon: float
    min_lat: float
    max_lon: float
    max_lat: float


@dataclass(slots=True)
class AttrSample:
    """One attribute's value in one notification.

    Not frozen: one is built per attribute on the ingest hot path, and a frozen
    dataclass's ``__init__`` costs several times more. Treat it as a value."""

    name: str
    ngsi_type: str  # as declared, or inferred for keyValues
    kind: Kind
    num: float | None = None
    txt: str | None = None
    js: str | None = None  # JSON text of the raw value (structured, geo, bool)
    geo: Geometry | None = None
    md: str | None = None  # JSON text of metadata / NGSI-LD sub-properties


@dataclass(slots=True)
class EntitySample:
    """All attributes of one entity in one notification, at one time index.

    All attributes share the entity's time index, as in QuantumLeap, so a wide
    history row can be rebuilt from them.
    """

    tenant: str  # "" is the default tenant
    service_path: str
    entity_id: str
    entity_type: str
    time_index: datetime  # timezone-aware UTC
    attrs: list[AttrSample] = field(default_factory=list)


@dataclass(frozen=True, slots=True)
class RejectedNotification:
    """A notification we answered with 4xx, kept so an operator can recover it."""

    tenant: str
    received_at: datetime
    error: str
    description: str
    headers: str  # JSON object text
    body: bytes  # as received, or its first bytes when body_truncated
    body_size: int | None = None  # bytes as received; None: len(body)
    body_truncated: bool = False
