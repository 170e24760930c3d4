"""Subscription notifications from Orion and Orion-LD → ``EntitySample``s.

One entry point, ``parse_notification``, for every format a broker sends:
NGSIv2 ``normalized``, ``keyValues``, ``simplifiedNormalized``,
``simplifiedKeyValues`` and ``values`` (told apart by the
``Ngsiv2-AttrsFormat`` header), NGSIv1 ``legacy``, and NGSI-LD
notifications, entities or GeoJSON features, in normalized, concise or
simplified (keyValues) form (the ``Ngsild-Attribute-Format`` header, or
``Ngsiv2-AttrsFormat``). Without a usable header the body's shape decides,
per attribute where formats can be mixed.

Every attribute name, entity id, entity type and service path must pass its
rule in ``names``, the rules the query parsers apply too: a name we could not
be asked for is refused here.

The parser is pure (no I/O) and on the ingest hot path: it walks the decoded
JSON once, builds samples directly, and raises only ``ParseError`` for input
it cannot use, so the route can answer 400 and keep the body for recovery.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Any

import orjson

from tsdb_service.core.errors import ParseError
from tsdb_service.core.model import AttrSample, EntitySample, Kind, ld_series_name
from tsdb_service.core.timepaths import NO_TIME_PATHS, TimePaths
from tsdb_service.core.valuesteps import Steps, extract, split_value_path
from tsdb_service.geo.encodings import GEOMETRY_TYPES
from tsdb_service.parse import timeindex
from tsdb_service.parse.names import ID_RULE, RULE, id_problem, name_problem
from tsdb_service.parse.request_context import notification_service_paths, notification_tenant
from tsdb_service.parse.text import nul_problem
from tsdb_service.parse.timeindex import FALLBACK_METADATA, TimeClues, parse_time, to_utc, watched_attributes
from tsdb_service.parse.values import TooDeep, attr_sample, to_json

DEFAULT_ENTITY_TYPE = "Thing"  # what Orion assigns when none is given
LD_NULL = "urn:ngsi-ld:null"  # NGSI-LD's value of a deleted attribute

# How the body is laid out.
_V2 = "v2"  # {"subscriptionId", "data": [entities]}
_V2_KEY_VALUES = "v2-keyValues"
_SIMPLIFIED = "simplified"  # the body is the entity
_SIMPLIFIED_KEY_VALUES = "simplified-keyValues"
_SIMPLIFIED_AUTO = "simplified-auto"  # header-less single entity
_VALUES = "values"  # {"subscriptionId", "data": [[v1, v2, ...]]}
_LD = "ld"  # {"type": "Notification", "data": [entities]}, normalized or concise
_LD_SIMPLIFIED = "ld-simplified"  # the same, every attribute its bare value
_GEOJSON = "geojson"  # {"type": "Notification", "data": FeatureCollection}
_GEOJSON_SIMPLIFIED = "geojson-simplified"
_V1 = "v1"  # {"contextResponses": [{"contextElement": ...}]}
_AUTO = "auto"  # no usable header: decide from the body

_FORMAT_HEADER = {
    "normalized": _V2,
    "keyvalues": _V2_KEY_VALUES,
    "simplifiednormalized": _SIMPLIFIED,
    "simplifiedkeyvalues": _SIMPLIFIED_KEY_VALUES,
    "values": _VALUES,
}

# Ngsild-Attribute-Format (Orion-LD writes Normalized, Concise, Simplified):
# does every attribute come as its bare value?
_LD_FORMAT_HEADER = {"normalized": False, "concise": False, "simplified": True, "keyvalues": True}

# How error messages locate an entity in the body.
_ENTITY_LABELS = {
    _SIMPLIFIED: "entity",
    _SIMPLIFIED_KEY_VALUES: "entity",
    _SIMPLIFIED_AUTO: "entity",
    _V1: "contextResponses",
    _GEOJSON: "data.features",
    _GEOJSON_SIMPLIFIED: "data.features",
}

# NGSIv1 tells same-named attributes apart by an "ID" metadata; each is its
# own attribute, stored as name + this + ID (a character NGSI names and URL
# path segments both allow unencoded).
V1_ID_SEPARATOR = "~"

_V2_ENTITY_KEYS = frozenset({"id", "type"})
_LD_ENTITY_KEYS = frozenset({"id", "type", "@context", "createdAt", "modifiedAt", "deletedAt", "scope"})

# NGSI-LD attribute type → the member holding its value.
_LD_VALUE_KEY = {
    "Property": "value",
    "GeoProperty": "value",
    "Relationship": "object",
    "LanguageProperty": "languageMap",
    "ListProperty": "valueList",
    "VocabProperty": "vocab",
    "JsonProperty": "json",
    "ListRelationship": "objectList",
}
# Concise form: no "type", the value member says what the attribute is.
_LD_CONCISE_TYPE = {key: ld_type for ld_type, key in _LD_VALUE_KEY.items() if ld_type != "GeoProperty"}

_VALUES_LAYOUT_HINT = (
    "values format needs the subscription's attribute list: register it with PUT /v2/notify/subscriptions/{id}"
)


@dataclass(frozen=True, slots=True)
class ValuesLayout:
    """What we know about a subscription, for Orion's ``values`` format."""

    attrs: tuple[str, ...]  # notification.attrs in order; may hold pseudo-names "id", "type"
    entity_id: str | None = None  # for layouts without an "id" column
    entity_type: str | None = None


@dataclass(slots=True)
class _Context:
    """Per-notification facts every entity needs."""

    watched: frozenset[str]
    header_attr: str | None
    received_at: datetime
    header_steps: Steps = ()  # Fiware-TimeIndex-Attribute names a value path: its stamp
    time_paths: TimePaths = NO_TIME_PATHS  # TSDB_TIME_INDEX_PATHS


def parse_notification(
    body: bytes,
    headers: Mapping[str, str],
    *,
    received_at: datetime,
    values_layout: Callable[[str, str], ValuesLayout | None] | None = None,
    time_paths: TimePaths = NO_TIME_PATHS,
) -> list[EntitySample]:
    """Every entity in one notification, ready to store (an entity whose
    attributes ``time_paths`` times by their own stamps gives one sample per time)."""
    doc = load_document(body)
    return parse_document(doc, headers, received_at=received_at, values_layout=values_layout, time_paths=time_paths)


def parse_document(
    doc: dict,
    headers: Mapping[str, str],
    *,
    received_at: datetime,
    values_layout: Callable[[str, str], ValuesLayout | None] | None = None,
    time_paths: TimePaths = NO_TIME_PATHS,
) -> list[EntitySample]:
    """``parse_notification`` of a body already decoded (``load_document``),
    e.g. the ``body`` member of an MQTT envelope (``ingest.mqtt``)."""
    pairs = _header_pairs(headers)
    hdrs = {name.lower(): value for name, value in pairs}  # the last of a repeated header
    format_header = hdrs.get("ngsiv2-attrsformat")
    layout = _layout(doc, format_header, hdrs.get("ngsild-attribute-format"))
    tenant = notification_tenant(pairs)
    header_attr, header_steps = _time_index_header(hdrs.get("fiware-timeindex-attribute", "").strip() or None)
    ctx = _Context(watched_attributes(header_attr), header_attr, to_utc(received_at), header_steps, time_paths)
    layout, entities = _entities(doc, layout, tenant, values_layout)
    paths = notification_service_paths(hdrs.get("fiware-servicepath"), len(entities))
    parse = _ENTITY_PARSERS[layout]
    label = _ENTITY_LABELS.get(layout, "data")
    out: list[EntitySample] = []
    for i, raw in enumerate(entities):
        out += _entity_samples(parse, raw, _where(label, i), tenant, paths[i], ctx)
    return out


def _time_index_header(text: str | None) -> tuple[str | None, Steps]:
    """``Fiware-TimeIndex-Attribute``: an attribute, or a value path into one
    (``odom(header.stamp)``) whose stamp is the time index."""
    if text is None or "(" not in text:
        return text, ()
    try:
        attr, steps = split_value_path(text)
    except ValueError as exc:
        raise ParseError(f"Fiware-TimeIndex-Attribute: {exc}") from None
    problem = name_problem(attr)
    if problem is not None:
        raise ParseError(f"Fiware-TimeIndex-Attribute: attribute name {attr[:80]!r} {problem}")
    return attr, steps


# --- envelope ------------------------------------------------------------------


def _header_pairs(headers: Mapping[str, str]) -> list[tuple[str, str]]:
    """Every ``(name, value)`` as text, repeats included (the tenant rule sees them all)."""
    try:
        return [(str(k), v if type(v) is str else _header_text(v)) for k, v in headers.items()]
    except AttributeError:
        raise ParseError("headers must be a mapping") from None


def _header_text(value: Any) -> str:
    if isinstance(value, (bytes, bytearray)):
        return bytes(value).decode("latin-1")
    return str(value)


def load_document(body: bytes) -> dict:
    """A notification body as JSON: an object without a NUL character
    anywhere (``parse.text``), else ``ParseError``."""
    try:
        doc = orjson.loads(body)
    except (orjson.JSONDecodeError, TypeError) as exc:
        raise ParseError(f"notification is not valid JSON: {exc}") from None
    if type(doc) is not dict:
        raise ParseError(f"notification must be a JSON object, got {_json_kind(doc)}")
    if (problem := nul_problem(body, doc)) is not None:
        raise ParseError(f"{problem}; the notification is kept in GET /v2/notify/rejected")
    return doc


def _layout(doc: dict, header: str | None, ld_header: str | None) -> str:
    """Header first, but an NGSI-LD envelope is unmistakable and wins."""
    declared = _FORMAT_HEADER.get(header.strip().lower()) if header else None
    if declared in (_SIMPLIFIED, _SIMPLIFIED_KEY_VALUES, _VALUES):
        return declared
    ld_simplified = _ld_simplified(ld_header, declared)
    if doc.get("type") == "Notification" and "data" in doc:
        if _is_geojson(doc["data"]):
            return _GEOJSON_SIMPLIFIED if ld_simplified else _GEOJSON
        return _LD_SIMPLIFIED if ld_simplified else _LD
    if ld_header is not None and declared is None and ("data" in doc or "id" in doc):
        return _LD_SIMPLIFIED if ld_simplified else _LD
    if declared is not None:
        return declared
    if "data" in doc:
        return _AUTO
    if "contextResponses" in doc:
        return _V1
    if "id" in doc:
        return _SIMPLIFIED_AUTO
    raise ParseError("unrecognised notification: expected a 'data' array, 'contextResponses', or an entity with 'id'")


def _ld_simplified(ld_header: str | None, declared: str | None) -> bool:
    """NGSI-LD attributes as bare values? ``Ngsild-Attribute-Format`` says,
    else an ``Ngsiv2-AttrsFormat: keyValues`` does. An unknown value is
    refused: guessing could store a value's own members as sub-properties."""
    if ld_header is None:
        return declared == _V2_KEY_VALUES
    simplified = _LD_FORMAT_HEADER.get(ld_header.strip().lower())
    if simplified is None:
        raise ParseError(
            f"unknown Ngsild-Attribute-Format {ld_header[:40]!r}: expected Normalized, Concise or Simplified"
        )
    return simplified


def _is_geojson(data: Any) -> bool:
    """Orion-LD's ``application/geo+json`` notifications carry a GeoJSON
    FeatureCollection (one Feature per entity) instead of an entity array."""
    return type(data) is dict and data.get("type") in ("FeatureCollection", "Feature")


def _entities(doc: dict, layout: str, tenant: str, values_layout) -> tuple[str, list]:
    """The raw entities, with values rows already turned into entities."""
    if layout in (_SIMPLIFIED, _SIMPLIFIED_KEY_VALUES, _SIMPLIFIED_AUTO):
        return layout, [doc]
    if layout == _V1:
        return layout, _v1_entities(doc)
    if layout in (_GEOJSON, _GEOJSON_SIMPLIFIED):
        return layout, _geojson_entities(doc["data"], simplified=layout == _GEOJSON_SIMPLIFIED)
    if layout in (_LD, _LD_SIMPLIFIED) and "data" not in doc:
        return layout, [doc]  # a bare entity with an Ngsild-Attribute-Format header
    entities = _data(doc)
    if layout == _VALUES or (layout == _AUTO and entities and type(entities[0]) is list):
        return _VALUES, _values_entities(doc, entities, tenant, values_layout)
    return layout, entities


def _data(doc: dict) -> list:
    data = doc.get("data")
    if type(data) is not list:
        raise ParseError(f"notification 'data' must be an array, got {_json_kind(data)}")
    return data


def _where(label: str, index: int) -> str:
    """Where an entity sits in the body, for error messages."""
    return label if label == "entity" else f"{label}[{index}]"


def _entity_samples(parse, raw: Any, where: str, tenant: str, path: str, ctx: _Context) -> list[EntitySample]:
    if type(raw) is not dict:
        raise ParseError(f"{where} must be an entity object, got {_json_kind(raw)}")
    clues = TimeClues(ctx.header_attr, ctx.watched, ctx.header_steps)
    try:
        entity_id, entity_type, attrs = parse(raw, where, clues)
    except TooDeep as exc:
        raise ParseError(f"{where}: {exc.description}") from None
    for attr in attrs:
        problem = name_problem(attr.name)
        if problem is not None:
            raise ParseError(
                f"{where}: attribute name {attr.name[:80]!r} {problem}; we store only names "
                f"every endpoint can be asked for: {RULE}"
            )
    deleted_at = _ld_entity_deleted_at(raw) if parse in _LD_ENTITY_PARSERS else None
    stamped: list[EntitySample] = []
    if ctx.time_paths:
        attrs, stamped = _split_stamped(attrs, ctx.time_paths, (tenant, path, entity_id, entity_type))
        if not attrs and deleted_at is None:
            return stamped
    time_index = clues.resolve(ctx.received_at)
    if clues.unusable:
        _mark_fallback(attrs, clues.unusable)
    return [EntitySample(tenant, path, entity_id, entity_type, time_index, attrs, deleted_at), *stamped]


def _split_stamped(
    attrs: list[AttrSample], rules: TimePaths, head: tuple[str, str, str, str]
) -> tuple[list[AttrSample], list[EntitySample]]:
    """The attributes ``rules`` time by their own stamp, taken off the entity's
    row: one ``EntitySample`` per stamp, each sample's ``observedAt`` that
    stamp (unless it has one), so an unchanged attribute the broker notifies
    again is recognised and stored once (``storage.ld_ingest``). The rest,
    and those whose stamp cannot be read (counted), stay at the entity's time."""
    rest: list[AttrSample] = []
    by_time: dict[datetime, list[AttrSample]] = {}
    for attr in attrs:
        steps = rules.steps(head[3], attr.name)
        moment = _stamp_of(attr, steps) if steps is not None else None
        if moment is None:
            if steps is not None:
                timeindex.on_stamp_fallback()
            rest.append(attr)
            continue
        if attr.observed_at is None:
            attr.observed_at = moment
        by_time.setdefault(moment, []).append(attr)
    return rest, [EntitySample(*head, moment, group) for moment, group in by_time.items()]


def _stamp_of(attr: AttrSample, steps: Steps) -> datetime | None:
    """The stamp at ``steps`` inside a structured sample's value."""
    if attr.kind is not Kind.STRUCTURED or not attr.js:
        return None
    return timeindex.read_stamp(extract(orjson.loads(attr.js), steps))


def _mark_fallback(attrs: list[AttrSample], unusable: tuple[str, ...]) -> None:
    """Record in each sample's metadata that its time is the reception time
    because these sources were not times (rare: the hot path never gets here).
    A sender's own metadata item of that name is kept as sent."""
    item = {"type": "StructuredValue", "value": list(unusable)}
    for attr in attrs:
        md = orjson.loads(attr.md) if attr.md else {}
        if FALLBACK_METADATA not in md:
            md[FALLBACK_METADATA] = item
            attr.md = orjson.dumps(md).decode()


# --- entity heads --------------------------------------------------------------


def _entity_id(entity: dict, where: str) -> str:
    entity_id = entity.get("id")
    if type(entity_id) is not str or not entity_id:
        raise ParseError(f"{where}: entity id must be a non-empty string, got {_json_kind(entity_id)}")
    _check_id(entity_id, "entity id", where)
    return entity_id


def _entity_type(entity: dict, where: str) -> str:
    """NGSI-LD may send a list of types: the first one names the entity."""
    entity_type = entity.get("type")
    if type(entity_type) is list and entity_type:
        entity_type = entity_type[0]
    if entity_type is None or entity_type == "" or entity_type == []:
        return DEFAULT_ENTITY_TYPE
    if type(entity_type) is not str:
        raise ParseError(f"{where}: entity type must be a string, got {_json_kind(entity_type)}")
    _check_id(entity_type, "entity type", where)
    return entity_type


def _check_id(value: str, what: str, where: str) -> None:
    problem = id_problem(value)
    if problem is not None:
        raise ParseError(
            f"{where}: {what} {value[:80]!r} {problem}; we store only ids and types every "
            f"endpoint can be asked for: {ID_RULE}"
        )


# --- NGSIv2 --------------------------------------------------------------------


def _v2_entity(entity: dict, where: str, clues: TimeClues) -> tuple[str, str, list[AttrSample]]:
    """Normalized, leniently: attributes that are not ``{type, value}``
    objects are read as keyValues values."""
    entity_id, entity_type = _entity_id(entity, where), _entity_type(entity, where)
    attrs = [_v2_attr(name, raw, clues) for name, raw in entity.items() if name not in _V2_ENTITY_KEYS]
    return entity_id, entity_type, attrs


def _v2_key_values_entity(entity: dict, where: str, clues: TimeClues) -> tuple[str, str, list[AttrSample]]:
    entity_id, entity_type = _entity_id(entity, where), _entity_type(entity, where)
    attrs = []
    for name, value in entity.items():
        if name not in _V2_ENTITY_KEYS:
            clues.note_value(name, value)
            attrs.append(attr_sample(name, None, value, None))
    return entity_id, entity_type, attrs


def _v2_attr(name: str, raw: Any, clues: TimeClues) -> AttrSample:
    if type(raw) is not dict or not _is_v2_attribute(raw):
        clues.note_value(name, raw)
        return attr_sample(name, None, raw, None)
    ngsi_type = raw.get("type")
    value = raw.get("value")
    metadata = raw.get("metadata")
    md = None
    if type(metadata) is dict and metadata:
        clues.note_metadata(metadata)
        md = to_json(metadata)
    clues.note_value(name, value)
    return attr_sample(name, ngsi_type if type(ngsi_type) is str else None, value, md)


def _is_v2_attribute(raw: dict) -> bool:
    """``{"type", "value", "metadata"}`` rather than a structured keyValues
    value (which may itself have a "type", like GeoJSON)."""
    return "value" in raw or ("type" in raw and ("metadata" in raw or len(raw) == 1))


# --- NGSI-LD -------------------------------------------------------------------


def _ld_entity(entity: dict, where: str, clues: TimeClues) -> tuple[str, str, list[AttrSample]]:
    entity_id, entity_type = _entity_id(entity, where), _entity_type(entity, where)
    clues.modified_at = entity.get("modifiedAt") or entity.get("deletedAt")
    attrs: list[AttrSample] = []
    for name, raw in entity.items():
        if name not in _LD_ENTITY_KEYS:
            attrs.extend(_ld_attrs(name, raw, clues, where))
    return entity_id, entity_type, attrs


def _ld_attrs(name: str, raw: Any, clues: TimeClues, where: str) -> list[AttrSample]:
    """One LD attribute: one sample per instance (a multi-attribute has one
    per datasetId; each non-default one is stored as ``name~datasetId``)."""
    if type(raw) is not list or not raw or not _is_instance_list(raw):
        return [_ld_attr(name, raw, clues)]
    samples, seen = [], set()
    for instance in raw:
        sample = _ld_attr(name, instance, clues)
        if sample.dataset_id in seen:
            which = "default instance" if sample.dataset_id is None else f"datasetId {sample.dataset_id[:80]!r}"
            raise ParseError(f"{where}: attribute {name[:80]!r} has its {which} twice")
        seen.add(sample.dataset_id)
        samples.append(sample)
    return samples


def _ld_attr(name: str, raw: Any, clues: TimeClues) -> AttrSample:
    """One LD attribute instance in normalized, concise or keyValues form."""
    if type(raw) is dict:
        _note_observed(raw, clues)
    if type(raw) is not dict:
        clues.note_value(name, raw)
        return attr_sample(name, "Property", raw, None)
    ld_type: Any = raw.get("type")  # JSON: any type until checked below
    key = _LD_VALUE_KEY.get(ld_type) if type(ld_type) is str else None
    if key is None:
        if type(ld_type) is str and ld_type in GEOMETRY_TYPES:
            return attr_sample(name, "GeoProperty", raw, None)  # concise GeoProperty
        key = next((k for k in _LD_CONCISE_TYPE if k in raw), None)
        if key is None:
            clues.note_value(name, raw)
            return attr_sample(name, "Property", raw, None)  # keyValues object
        if type(ld_type) is not str or not ld_type:
            ld_type = _LD_CONCISE_TYPE[key]
    elif key not in raw and "value" in raw:
        key = "value"  # NGSIv2 habit, e.g. a Relationship with "value"
    value = raw.get(key)
    clues.note_value(name, value)
    return _ld_instance(name, ld_type, value, raw, key)


def _ld_instance(name: str, ld_type: str, value: Any, raw: dict, key: str) -> AttrSample:
    """The sample of one instance with its own NGSI-LD times and datasetId.
    A deletion (``deletedAt``, or the value ``urn:ngsi-ld:null``) is stored
    as a null value with its deletion time."""
    md = _ld_metadata(raw, key)
    if md is None and value != LD_NULL:
        return attr_sample(name, ld_type, value, None)
    dataset = raw.get("datasetId")
    if dataset is not None and (type(dataset) is not str or not dataset):
        raise ParseError(
            f"attribute {name[:80]!r}: datasetId must be a non-empty string (a URI), got {_json_kind(dataset)}"
        )
    deleted = "deletedAt" in raw or value == LD_NULL
    sample = attr_sample(ld_series_name(name, dataset), ld_type, None if deleted else value, md)
    sample.dataset_id = dataset
    sample.observed_at = parse_time(raw.get("observedAt"))
    sample.created_at = parse_time(raw.get("createdAt"))
    sample.modified_at = parse_time(raw.get("modifiedAt"))
    if deleted:
        sample.deleted_at = (
            parse_time(raw.get("deletedAt")) or sample.modified_at or sample.observed_at or datetime.now(UTC)
        )
    return sample


def parse_ld_instance(name: str, raw: Any) -> AttrSample:
    """One attribute instance of an NGSI-LD temporal write (``POST
    /ngsi-ld/v1/temporal/entities`` ...), read exactly as a notified one.
    It must be an attribute object (normalized or concise); the stored
    name is checked against the one naming rule."""
    if type(raw) is not dict:
        raise ParseError(f"attribute {name[:80]!r}: each instance must be an attribute object, got {_json_kind(raw)}")
    if not _is_instance_list([raw]) and raw.get("type") not in GEOMETRY_TYPES:
        raise ParseError(
            f"attribute {name[:80]!r}: an instance needs an NGSI-LD type (Property, Relationship, "
            "GeoProperty, ...) or a value member (value, object, languageMap, ...)"
        )
    sample = _ld_attr(name, raw, TimeClues(None, frozenset()))
    problem = name_problem(sample.name)
    if problem is not None:
        raise ParseError(
            f"attribute name {sample.name[:80]!r} {problem}; we store only names every endpoint "
            f"can be asked for: {RULE}"
        )
    return sample


def _ld_entity_deleted_at(entity: dict) -> datetime | None:
    """An NGSI-LD entity deletion (``deletedAt`` on the entity): when."""
    deleted = entity.get("deletedAt")
    if deleted is None:
        return None
    return parse_time(deleted) or datetime.now(UTC)


def _ld_metadata(raw: dict, key: str) -> str | None:
    """Sub-properties (observedAt, unitCode, datasetId, nested properties)."""
    if len(raw) == ("type" in raw) + (key in raw):
        return None
    extra = {k: v for k, v in raw.items() if k != "type" and k != key}
    return to_json(extra) if extra else None


def _ld_simplified_entity(entity: dict, where: str, clues: TimeClues) -> tuple[str, str, list[AttrSample]]:
    """Simplified (keyValues): each attribute is its value, whatever its
    shape. An object stays the object (``{"value": 5, "unit": "m"}`` is not
    a Property of 5); a GeoJSON geometry is a GeoProperty, for geo-queries."""
    entity_id, entity_type = _entity_id(entity, where), _entity_type(entity, where)
    clues.modified_at = entity.get("modifiedAt") or entity.get("deletedAt")
    attrs = []
    for name, value in entity.items():
        if name not in _LD_ENTITY_KEYS:
            clues.note_value(name, value)
            geometry = type(value) is dict and value.get("type") in GEOMETRY_TYPES and "coordinates" in value
            attrs.append(attr_sample(name, "GeoProperty" if geometry else "Property", value, None))
    return entity_id, entity_type, attrs


def _geojson_entities(data: dict, *, simplified: bool) -> list:
    """GeoJSON features → NGSI-LD entities: the feature's ``id`` is the
    entity id, ``properties.type`` its type, the other properties its
    attributes. Orion-LD derives ``geometry`` from one of those attributes
    (``location`` unless the subscription names another); a geometry no
    attribute carries is kept as ``location``."""
    if data.get("type") == "Feature":
        features: Any = [data]
    else:
        features = data.get("features")
        if type(features) is not list:
            raise ParseError(f"GeoJSON notification 'data.features' must be an array, got {_json_kind(features)}")
    return [_feature_entity(feature, i, simplified) for i, feature in enumerate(features)]


def _feature_entity(feature: Any, index: int, simplified: bool) -> Any:
    if type(feature) is not dict:
        return feature  # reported by _entity_samples with its position
    properties = feature.get("properties")
    if properties is None:
        properties = {}
    elif type(properties) is not dict:
        raise ParseError(f"data.features[{index}]: 'properties' must be an object, got {_json_kind(properties)}")
    entity = {"id": feature.get("id"), "type": properties.get("type")}
    entity.update((name, value) for name, value in properties.items() if name != "type")
    geometry = feature.get("geometry")
    if type(geometry) is dict and "location" not in entity and not _carried(geometry, properties):
        entity["location"] = geometry if simplified else {"type": "GeoProperty", "value": geometry}
    return entity


def _carried(geometry: dict, properties: dict) -> bool:
    """Does an attribute (in any of the three forms) hold this geometry?"""
    for value in properties.values():
        if value == geometry or (type(value) is dict and value.get("value") == geometry):
            return True
    return False


def _is_instance_list(items: list) -> bool:
    """A multi-attribute (several datasetIds) rather than an array value."""
    for item in items:
        if type(item) is not dict:
            return False
        ld_type = item.get("type")
        if not (type(ld_type) is str and ld_type in _LD_VALUE_KEY) and _LD_CONCISE_TYPE.keys().isdisjoint(item):
            return False
    return True


def _note_observed(raw: dict, clues: TimeClues) -> None:
    observed = raw.get("observedAt")
    if observed is not None:
        clues.observed_at.append(observed)


def _looks_ld(entity: dict) -> bool:
    """For header-less bodies: any NGSI-LD attribute marks the entity as LD.

    An LD attribute has an LD type *and* that type's value member and no
    NGSIv2 "metadata": NGSIv2 entities commonly use the type "Relationship"
    with a "value", which must stay NGSIv2.
    """
    if "@context" in entity:
        return True
    for name, raw in entity.items():
        if type(raw) is list and raw and type(raw[0]) is dict:
            raw = raw[0]
        if type(raw) is dict and name not in _V2_ENTITY_KEYS and "metadata" not in raw:
            ld_type = raw.get("type")
            if type(ld_type) is str and _LD_VALUE_KEY.get(ld_type, "-") in raw:
                return True
    return False


def _auto_entity(entity: dict, where: str, clues: TimeClues) -> tuple[str, str, list[AttrSample]]:
    parse = _ld_entity if _looks_ld(entity) else _v2_entity
    return parse(entity, where, clues)


# --- values and legacy -----------------------------------------------------------


def _values_entities(doc: dict, rows: list, tenant: str, lookup) -> list[dict]:
    """Rows of bare values → keyValues entities, using the registered layout."""
    subscription = doc.get("subscriptionId")
    if type(subscription) is not str or not subscription:
        raise ParseError("values format needs a 'subscriptionId' string to find the attribute list")
    layout = lookup(tenant, subscription) if lookup is not None else None
    if layout is None:
        raise ParseError(f"{_VALUES_LAYOUT_HINT} (subscription {subscription!r} is unknown)")
    names = tuple(layout.attrs)
    if "id" not in names and not layout.entity_id:
        raise ParseError(f"values layout of subscription {subscription!r} has neither an 'id' column nor an entity id")
    return [_values_row(row, i, names, layout) for i, row in enumerate(rows)]


def _values_row(row: Any, index: int, names: tuple[str, ...], layout: ValuesLayout) -> dict:
    if type(row) is not list:
        raise ParseError(f"data[{index}] must be an array of values, got {_json_kind(row)}")
    if len(row) != len(names):
        raise ParseError(f"data[{index}] has {len(row)} values but the subscription lists {len(names)} attributes")
    entity = {"id": layout.entity_id, "type": layout.entity_type}
    entity.update(zip(names, row, strict=True))
    return entity


def _values_entity(entity: dict, where: str, clues: TimeClues) -> tuple[str, str, list[AttrSample]]:
    return _v2_key_values_entity(entity, where, clues)


def _v1_entities(doc: dict) -> list:
    """NGSIv1 ``legacy`` → NGSIv2 normalized entities (metadatas → metadata)."""
    responses = doc.get("contextResponses")
    if type(responses) is not list:
        raise ParseError(f"'contextResponses' must be an array, got {_json_kind(responses)}")
    return [_v1_entity(response, i) for i, response in enumerate(responses)]


def _v1_entity(response: Any, index: int) -> dict:
    element = response.get("contextElement") if type(response) is dict else None
    if type(element) is not dict:
        raise ParseError(f"contextResponses[{index}] needs a 'contextElement' object")
    attributes = element.get("attributes", [])
    if type(attributes) is not list:
        raise ParseError(f"contextResponses[{index}]: 'attributes' must be an array")
    entity = {"id": element.get("id"), "type": element.get("type")}
    for attribute in attributes:
        name = attribute.get("name") if type(attribute) is dict else None
        if type(name) is not str or name in _V2_ENTITY_KEYS:
            raise ParseError(f"contextResponses[{index}]: each attribute needs a 'name' string other than id/type")
        metadata = _v1_metadata(attribute)
        key = _v1_attr_name(name, metadata)
        if key in entity:
            raise ParseError(
                f"contextResponses[{index}]: attribute {key[:80]!r} appears twice; NGSIv1 tells "
                "same-named attributes apart by an 'ID' metadata, and these have the same one or none"
            )
        entity[key] = {"type": attribute.get("type"), "value": attribute.get("value"), "metadata": metadata}
    return entity


def _v1_attr_name(name: str, metadata: dict) -> str:
    """``temperature`` with ``ID`` metadata ``ground`` → ``temperature~ground``:
    in NGSIv1 the ID is part of the attribute's identity (two attributes
    may share a name), so it is part of the stored name; the ID metadata
    is kept too."""
    instance = metadata.get("ID", {}).get("value")
    if type(instance) is bool or type(instance) not in (str, int, float) or instance == "":
        return name
    return f"{name}{V1_ID_SEPARATOR}{instance}"


def _v1_metadata(attribute: dict) -> dict:
    items = attribute.get("metadatas")
    if type(items) is not list:
        return {}
    return {
        m["name"]: {"type": m.get("type"), "value": m.get("value")}
        for m in items
        if type(m) is dict and type(m.get("name")) is str
    }


_LD_ENTITY_PARSERS = frozenset({_ld_entity, _ld_simplified_entity})

_ENTITY_PARSERS = {
    _V2: _v2_entity,
    _V2_KEY_VALUES: _v2_key_values_entity,
    _SIMPLIFIED: _v2_entity,
    _SIMPLIFIED_AUTO: _auto_entity,
    _SIMPLIFIED_KEY_VALUES: _v2_key_values_entity,
    _VALUES: _values_entity,
    _LD: _ld_entity,
    _LD_SIMPLIFIED: _ld_simplified_entity,
    _GEOJSON: _ld_entity,
    _GEOJSON_SIMPLIFIED: _ld_simplified_entity,
    _V1: _v2_entity,
    _AUTO: _auto_entity,
}


def _json_kind(value: Any) -> str:
    """JSON's name for a value's type, for error messages."""
    if value is None:
        return "null"
    if type(value) is bool:
        return "a boolean"
    if type(value) in (int, float):
        return "a number"
    if type(value) is str:
        return "a string" if value else "an empty string"
    if type(value) is list:
        return "an array"
    return "an object"
