"""QuantumLeap's rows → ``EntitySample``s, as if their notifications had arrived.

Pure (no SQL, no I/O): the reader hands over one row as a dict of column →
the value the PostgreSQL driver returned, plus the table's entry in
``md_ets_metadata``; this module gives the entity sample our store keeps.

What QuantumLeap stores, per its translators (read there, not copied):

* each attribute in a lower-cased column; ``md_ets_metadata.entity_attrs``
  maps it back to ``[original name, NGSI type]``; ``entity_id``,
  ``entity_type`` and ``time_index`` are in the map too, as ``id``, ``type``
  and ``time_index``; ``fiware_servicepath``, ``instanceid`` and
  ``__original_ngsi_entity__`` are not;
* a ``NULL`` column: the notification did not carry that attribute (or its
  value did not fit the column): an absent attribute, not a null sample;
* TimescaleDB: geometries as PostGIS ``geometry`` (the driver returns
  hex EWKB), answered as GeoJSON for ``geo:json``/``GeoProperty`` and as the
  ``"lat, lon"`` text (lists of them for lines, polygons and boxes) for the
  simple-location types; objects and arrays as ``jsonb``;
* CrateDB: ``geo:point`` as a ``geo_point`` ([lon, lat]; over the
  PostgreSQL protocol the text ``(lon,lat)``), GeoJSON as a ``geo_shape``
  object, objects as ``object``, arrays as ``array(text)``, timestamps in
  milliseconds since the epoch on its HTTP interface;
* a batch that failed to insert: a row per entity with only ``entity_id``,
  ``entity_type``, ``time_index`` (the time of the failure) and
  ``__original_ngsi_entity__`` = ``{"data": entity, "error", "failedBatchID"}``
  (on CrateDB ``data`` is the entity's JSON text).

Values are rebuilt to what QuantumLeap's API answers for them and then
stored through ``parse.values.attr_sample``, the path every notification
takes, so our QuantumLeap API reads them back the way QuantumLeap would.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta
from enum import StrEnum
from typing import Any

import shapely
from shapely.errors import GEOSException

from tsdb_service.core.model import AttrSample, EntitySample
from tsdb_service.parse.timeindex import parse_time
from tsdb_service.parse.values import attr_sample

METADATA_TABLE = "md_ets_metadata"
TENANT_PREFIX = "mt"
TYPE_PREFIX = "et"
ORIGINAL_ENTITY = "__original_ngsi_entity__"
ID, TYPE, TIME_INDEX, SERVICE_PATH = "entity_id", "entity_type", "time_index", "fiware_servicepath"
# Columns of every table that are not attributes.
HOUSEKEEPING = frozenset({ID, TYPE, TIME_INDEX, SERVICE_PATH, "instanceid", ORIGINAL_ENTITY})
# Keys of an original entity that are not attributes.
_ENTITY_KEYS = frozenset({"id", "type", TIME_INDEX, "@context"})

GEOJSON_TYPES = frozenset({"geo:json", "geoproperty"})
SLF_TYPES = frozenset({"geo:point", "geo:line", "geo:polygon", "geo:box"})
DATETIME_TYPES = frozenset({"datetime", "iso8601"})
JSON_TYPES = GEOJSON_TYPES | {"structuredvalue", "array"}
_EPOCH = datetime(1970, 1, 1, tzinfo=UTC)


class Dialect(StrEnum):
    """Which QuantumLeap backend wrote the tables."""

    POSTGRESQL = "postgresql"  # TimescaleDB or plain PostgreSQL (+ PostGIS)
    CRATE = "crate"

    @property
    def default_schema(self) -> str:
        """Where a table without a tenant lives."""
        return "doc" if self is Dialect.CRATE else "public"


@dataclass(frozen=True, slots=True)
class TableMeta:
    """One QuantumLeap table: where it is, whose it is, what its columns mean."""

    name: str  # as md_ets_metadata spells it: '"mtacme"."etroom"' or '"etroom"'
    schema: str
    table: str
    tenant: str  # "" without a tenant; lower-cased, as QuantumLeap keeps it
    entity_type: str  # the type as first notified (from the rows), else the table's
    attrs: dict[str, tuple[str, str | None]]  # column → (original name, NGSI type)


def split_table_name(name: str, dialect: Dialect) -> tuple[str, str] | None:
    """(schema, table) of a ``md_ets_metadata.table_name``, or None if it is
    not one QuantumLeap writes (``"mt<tenant>"."et<type>"`` or ``"et<type>"``)."""
    parts = [p.strip('"') for p in _split_quoted(name)]
    if len(parts) == 1 and parts[0].startswith(TYPE_PREFIX):
        return dialect.default_schema, parts[0]
    if len(parts) == 2 and parts[0].startswith(TENANT_PREFIX) and parts[1].startswith(TYPE_PREFIX):
        return parts[0], parts[1]
    return None


def _split_quoted(name: str) -> list[str]:
    """``"a"."b"`` → [``"a"``, ``"b"``]; a dot inside quotes does not split."""
    parts, current, quoted = [], "", False
    for ch in name:
        if ch == '"':
            quoted = not quoted
        if ch == "." and not quoted:
            parts.append(current)
            current = ""
        else:
            current += ch
    parts.append(current)
    return parts


def table_meta(name: str, entity_attrs: Any, dialect: Dialect) -> TableMeta | None:
    """A table's description from its metadata row, or None if the row is not
    QuantumLeap's (another application's table of that name)."""
    where = split_table_name(name, dialect)
    attrs_map = _json(entity_attrs)
    if where is None or not isinstance(attrs_map, dict):
        return None
    schema, table = where
    tenant = schema[len(TENANT_PREFIX) :] if schema != dialect.default_schema else ""
    attrs: dict[str, tuple[str, str | None]] = {}
    for column, described in attrs_map.items():
        if column in HOUSEKEEPING or not isinstance(described, list | tuple) or not described:
            continue
        original = str(described[0])
        ngsi_type = described[1] if len(described) > 1 and isinstance(described[1], str) else None
        attrs[str(column).lower()] = (original, ngsi_type)
    return TableMeta(name, schema, table, tenant, table[len(TYPE_PREFIX) :], attrs)


@dataclass(frozen=True, slots=True)
class Unreadable:
    """A row that cannot be imported: why, and where it is."""

    table: str
    entity_id: str | None
    time_index: str
    reason: str


def row_to_entity(meta: TableMeta, row: Mapping[str, Any], dialect: Dialect) -> EntitySample | Unreadable:
    """The entity sample a row stands for. A failed-batch row is rebuilt from
    its original entity; a row with nothing in it is ``Unreadable``."""
    moment = to_datetime(row.get(TIME_INDEX))
    eid, etype = row.get(ID), row.get(TYPE)
    if moment is None:
        return Unreadable(meta.name, eid, str(row.get(TIME_INDEX)), "time_index is not a time")
    if row.get(ORIGINAL_ENTITY) is not None and not _has_values(meta, row):
        return _from_original(meta, row, moment)
    attrs = [_attr(name, ngsi_type, row[col], dialect) for col, (name, ngsi_type) in meta.attrs.items()]
    present = [a for a in attrs if a is not None]
    if not isinstance(eid, str) or not isinstance(etype, str):
        return Unreadable(meta.name, None, iso(moment), "entity_id or entity_type is missing")
    if not present:
        return Unreadable(meta.name, eid, iso(moment), "every attribute column is NULL")
    return EntitySample(meta.tenant, row.get(SERVICE_PATH) or "/", eid, etype, moment, present)


def _has_values(meta: TableMeta, row: Mapping[str, Any]) -> bool:
    return any(row.get(col) is not None for col in meta.attrs)


def _attr(name: str, ngsi_type: str | None, stored: Any, dialect: Dialect) -> AttrSample | None:
    if stored is None:
        return None  # the notification did not carry it
    return attr_sample(name, ngsi_type, ngsi_value(stored, ngsi_type, dialect), None)


def _from_original(meta: TableMeta, row: Mapping[str, Any], failed_at: datetime) -> EntitySample | Unreadable:
    """A failed batch's row: the entity QuantumLeap received, at its own time index."""
    where = (meta.name, row.get(ID), iso(failed_at))
    wrapper = _json(row[ORIGINAL_ENTITY])
    entity = _json(wrapper.get("data")) if isinstance(wrapper, dict) else None
    if not isinstance(entity, dict) or not isinstance(entity.get("id"), str):
        return Unreadable(*where, "failed-batch row whose original entity cannot be parsed")
    moment = to_datetime(entity.get(TIME_INDEX)) or failed_at
    attrs = []
    for name, attr in entity.items():
        if name in _ENTITY_KEYS:
            continue
        if isinstance(attr, dict) and ("value" in attr or "object" in attr):
            value = attr["value"] if "value" in attr else attr["object"]
            declared = attr.get("type") if isinstance(attr.get("type"), str) else None
            attrs.append(attr_sample(name, declared, value, None))
        else:
            attrs.append(attr_sample(name, None, attr, None))
    if not attrs:
        return Unreadable(*where, "failed-batch row whose original entity has no attributes")
    etype = entity.get("type") if isinstance(entity.get("type"), str) else row.get(TYPE)
    return EntitySample(meta.tenant, row.get(SERVICE_PATH) or "/", entity["id"], str(etype), moment, attrs)


# --- values, per NGSI type and backend --------------------------------------------


def ngsi_value(stored: Any, ngsi_type: str | None, dialect: Dialect) -> Any:
    """The value QuantumLeap answers for a stored one."""
    kind = (ngsi_type or "").lower()
    if kind in DATETIME_TYPES:
        moment = to_datetime(stored)
        return iso(moment) if moment is not None else stored
    if (
        dialect is Dialect.POSTGRESQL
        and isinstance(stored, str | bytes)
        and (kind in GEOJSON_TYPES or kind in SLF_TYPES)
    ):
        return _from_ewkb(stored, kind)
    if dialect is Dialect.CRATE and kind == "geo:point":
        return _crate_point(stored)
    if isinstance(stored, str) and kind in JSON_TYPES:
        decoded = _json(stored)  # objects and shapes may come as JSON text
        return decoded if isinstance(decoded, dict | list) else stored
    if isinstance(stored, tuple):
        return list(stored)
    return stored


def _from_ewkb(stored: str | bytes, kind: str) -> Any:
    """A PostGIS geometry (hex EWKB, as the driver returns it) → GeoJSON, or
    the simple-location text QuantumLeap answers for ``geo:point`` & co."""
    try:
        shape = shapely.from_wkb(stored)
    except (GEOSException, ValueError, TypeError):
        return stored  # not a geometry after all: kept as text
    geojson = _lists(shapely.geometry.mapping(shape))
    if kind in GEOJSON_TYPES:
        return geojson
    coords = geojson.get("coordinates")
    if kind == "geo:point" and geojson["type"] == "Point":
        return lat_lon(coords)
    if kind == "geo:line" and geojson["type"] == "LineString":
        return [lat_lon(p) for p in coords]
    if kind == "geo:polygon" and geojson["type"] == "Polygon":
        return [lat_lon(p) for p in coords[0]]
    if kind == "geo:box" and geojson["type"] == "Polygon":
        ring = coords[0]  # stored as [top left, top right, bottom right, bottom left, top left]
        return [lat_lon(ring[2]), lat_lon(ring[0])]
    return geojson


def _crate_point(stored: Any) -> Any:
    """A CrateDB ``geo_point``: [lon, lat] (HTTP), ``(lon,lat)`` text (PostgreSQL
    protocol) or GeoJSON → ``"lat, lon"``."""
    if isinstance(stored, str) and stored.startswith("(") and stored.endswith(")"):
        parts = stored[1:-1].split(",")
        try:
            stored = [float(p) for p in parts]
        except ValueError:
            return stored
    if isinstance(stored, dict) and stored.get("type") == "Point":
        stored = stored.get("coordinates")
    if isinstance(stored, list | tuple) and len(stored) == 2:
        return lat_lon(stored)
    return stored


def lat_lon(position: Any) -> str:
    """``[lon, lat]`` → ``"lat, lon"``, the numbers as Python prints floats
    (what QuantumLeap answers)."""
    return f"{float(position[1])}, {float(position[0])}"


def _lists(value: Any) -> Any:
    if isinstance(value, dict):
        return {k: _lists(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_lists(v) for v in value]
    return value


def _json(value: Any) -> Any:
    if isinstance(value, bytes | bytearray | memoryview):
        value = bytes(value).decode("utf-8", "replace")
    if isinstance(value, str):
        try:
            return json.loads(value)
        except ValueError:
            return None
    return value


def to_datetime(value: Any) -> datetime | None:
    """A stored time as an aware UTC datetime: a driver's datetime (a naive one
    is UTC), CrateDB's milliseconds since the epoch, or ISO text."""
    if isinstance(value, datetime):
        return value.replace(tzinfo=UTC) if value.tzinfo is None else value.astimezone(UTC)
    if isinstance(value, int | float) and not isinstance(value, bool):
        return _EPOCH + timedelta(milliseconds=value)
    if isinstance(value, str):
        return parse_time(value)
    return None


def iso(moment: datetime) -> str:
    """QuantumLeap's spelling of a time: UTC, milliseconds, ``+00:00``."""
    return moment.astimezone(UTC).isoformat(timespec="milliseconds")


def duplicate_key(entity: EntitySample) -> tuple:
    """What makes two rows the same notification stored twice: everything
    but QuantumLeap's per-row ``instanceid``."""
    return (
        entity.service_path,
        entity.entity_id,
        entity.entity_type,
        entity.time_index,
        tuple((a.name, a.ngsi_type, a.kind, a.num, a.txt, a.js) for a in entity.attrs),
    )
