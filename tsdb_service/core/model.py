"""The ingest data model: what a parsed notification becomes before storage.

The parser (``tsdb_service.parse``) produces these; every storage backend
consumes them. They carry no SQL and no HTTP, so both sides can be tested on
their own.
"""

from __future__ import annotations

import json
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
    ngsi_type: str | None  # as declared, or inferred for keyValues
    kind: Kind
    num: float | None = None
    txt: str | None = None
    js: str | None = None  # JSON text of the raw value (structured, geo, bool)
    geo: Geometry | None = None
    md: str | None = None  # JSON text of metadata / NGSI-LD sub-properties
    # NGSI-LD, per instance (all None for NGSIv2/v1 samples): the
    # instance's own observedAt, the broker's createdAt/modifiedAt, the time
    # of a deletion (value urn:ngsi-ld:null), and a non-default datasetId
    # (the sample's ``name`` is then ``attr~datasetId``, see ``ld_series_name``).
    observed_at: datetime | None = None
    created_at: datetime | None = None
    modified_at: datetime | None = None
    deleted_at: datetime | None = None
    dataset_id: str | None = None


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
    # NGSI-LD entity deletion: every stored attribute of the entity (same
    # tenant, service path, id and type) that ``attrs`` does not name gets a
    # deletion instance at this time when the sample is stored.
    deleted_at: datetime | None = None
    # The row id the ingest log gave it (``write.logged``): stored as given, so
    # replaying the log after a crash skips what the database already holds.
    # None: the store allocates one when it stages the sample.
    rid: int | None = None


# NGSI-LD keeps several instances of one attribute apart by datasetId; the
# NGSIv2 API needs one value per attribute per row, so a non-default
# instance is stored as its own attribute ``name~datasetId``, as NGSIv1
# attributes with an ``ID`` metadata are (``parse.notification.V1_ID_SEPARATOR``).
DATASET_SEPARATOR = "~"


def ld_series_name(attr: str, dataset_id: str | None) -> str:
    """The stored (NGSIv2-visible) attribute name of an NGSI-LD instance."""
    return attr if dataset_id is None else f"{attr}{DATASET_SEPARATOR}{dataset_id}"


def ld_attr_name(series_attr: str, dataset_id: str | None) -> str:
    """The NGSI-LD attribute name back from a stored one and its datasetId."""
    if dataset_id is None:
        return series_attr
    return series_attr[: len(series_attr) - len(dataset_id) - len(DATASET_SEPARATOR)]


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
    topic: str | None = None  # the MQTT topic it came on; None: over HTTP


INSTANCE_URN_PREFIX = "urn:ngsi-ld:attribute:instance:"


def instance_urn(iid: int) -> str:
    """The NGSI-LD ``instanceId`` of the sample with instance id ``iid``:
    derived from the stored id, so it survives compaction and restarts."""
    return f"{INSTANCE_URN_PREFIX}{iid:016x}"


def client_instance_id(md: str | None) -> str | None:
    """The ``instanceId`` a client gave an NGSI-LD instance, kept with its
    other members in ``md`` (JSON text), or None."""
    if not md or '"instanceId"' not in md:
        return None
    try:
        meta = json.loads(md)
    except ValueError:
        return None
    found = meta.get("instanceId") if isinstance(meta, dict) else None
    return found if isinstance(found, str) else None


def instance_iid(urn: str) -> int | None:
    """The stored instance id an ``instanceId`` names, or None if it is not one of ours."""
    if not urn.startswith(INSTANCE_URN_PREFIX):
        return None
    digits = urn[len(INSTANCE_URN_PREFIX) :]
    if not 1 <= len(digits) <= 16 or any(c not in "0123456789abcdef" for c in digits):
        return None
    return int(digits, 16)
