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

**The ingest rules apply.** QuantumLeap stored names our API refuses (it
has its own rules, or none): what it kept is imported only if a
notification carrying it would have been accepted, since what the API
cannot name it can neither read nor delete. A tenant outside the tenant
rule refuses its tables (``table_meta``), an attribute name outside the
name rule its column, an entity id, type or service path outside theirs
its row (``Unreadable``), and a value no backend can hold (a NUL, nesting
past the limit) that value (``Dropped``); each is counted and reported,
never stored. Odd column types (``numeric``, ``interval``, ``bytea``,
``uuid``, arrays, ``money``...) are turned into plain JSON values
(``plain_value``), never a traceback.
"""

from __future__ import annotations

import base64
import ipaddress
import json
import math
import uuid
from collections.abc import Mapping
from dataclasses import dataclass, field
from datetime import UTC, date, datetime, time, timedelta
from decimal import Decimal
from enum import StrEnum
from typing import Any

import shapely
from shapely.errors import GEOSException

from tsdb_service.core.errors import ParseError
from tsdb_service.core.model import AttrSample, EntitySample
from tsdb_service.parse.names import (
    ID_RULE,
    RULE,
    SERVICE_PATH_RULE,
    id_problem,
    name_problem,
    normalize_service_path,
    service_path_problem,
)
from tsdb_service.parse.request_context import is_stored_tenant
from tsdb_service.parse.text import NUL_RULE, nul_path
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
    # Columns md_ets_metadata describes that are not imported → why (a name
    # the API refuses, a description that is no [name, type]).
    refused: dict[str, str] = field(default_factory=dict)


@dataclass(frozen=True, slots=True)
class SkippedTable:
    """A table of QuantumLeap's (by its name) that is not imported, and why."""

    name: str
    reason: str


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


def table_meta(name: Any, entity_attrs: Any, dialect: Dialect) -> TableMeta | SkippedTable | None:
    """A table's description from its metadata row; ``SkippedTable`` when
    the row names one of QuantumLeap's tables that cannot be imported (an
    ``entity_attrs`` that is no JSON object, a tenant the API refuses);
    None if the row is not QuantumLeap's (another application's table)."""
    if not isinstance(name, str):
        return None
    where = split_table_name(name, dialect)
    if where is None:
        return None
    schema, table = where
    attrs_map = _json(entity_attrs)
    if not isinstance(attrs_map, dict):
        shown = "NULL" if entity_attrs is None else repr(str(entity_attrs)[:60])
        return SkippedTable(name, f"md_ets_metadata.entity_attrs is {shown}, not a JSON object of columns")
    tenant = schema[len(TENANT_PREFIX) :].lower() if schema != dialect.default_schema else ""
    if not is_stored_tenant(tenant):
        return SkippedTable(
            name, f"tenant {tenant[:60]!r} is not one the API serves (1 to 50 letters, digits or underscores)"
        )
    attrs: dict[str, tuple[str, str | None]] = {}
    refused: dict[str, str] = {}
    for column, described in attrs_map.items():
        if column in HOUSEKEEPING:
            continue
        col = str(column).lower()
        if not isinstance(described, list | tuple) or not described or not isinstance(described[0], str):
            refused[col] = f"md_ets_metadata describes it as {str(described)[:60]!r}, not [name, type]"
            continue
        original = described[0]
        if (problem := name_problem(original)) is not None:
            refused[col] = f"attribute name {original[:80]!r} {problem}: {RULE}"
            continue
        ngsi_type = described[1] if len(described) > 1 and isinstance(described[1], str) else None
        if ngsi_type is not None and "\0" in ngsi_type:
            ngsi_type = None  # a type no backend can hold: inferred from the values instead
        attrs[col] = (original, ngsi_type)
    return TableMeta(name, schema, table, tenant, table[len(TYPE_PREFIX) :], attrs, refused)


@dataclass(frozen=True, slots=True)
class Unreadable:
    """A row that cannot be imported: why, and where it is."""

    table: str
    entity_id: str | None
    time_index: str
    reason: str


@dataclass(frozen=True, slots=True)
class Dropped:
    """One value of a row that is not imported (the rest of the row is): where and why."""

    attr: str
    entity_id: str
    time_index: str
    reason: str


def row_to_entity(
    meta: TableMeta, row: Mapping[str, Any], dialect: Dialect, dropped: list[Dropped] | None = None
) -> EntitySample | Unreadable:
    """The entity sample a row stands for. A failed-batch row is rebuilt from
    its original entity; a row with nothing in it, or naming what the API
    refuses, is ``Unreadable``; values that cannot be stored are left out
    and added to ``dropped``."""
    dropped = [] if dropped is None else dropped  # this row's: empty when given
    moment = to_datetime(row.get(TIME_INDEX))
    eid, etype = row.get(ID), row.get(TYPE)
    if moment is None:
        return Unreadable(meta.name, _shown(eid), str(row.get(TIME_INDEX)), "time_index is not a time")
    if row.get(ORIGINAL_ENTITY) is not None and not _has_values(meta, row):
        return _from_original(meta, row, moment, dropped)
    if not isinstance(eid, str) or not isinstance(etype, str):
        return Unreadable(meta.name, None, iso(moment), "entity_id or entity_type is missing")
    where = (meta.name, eid, iso(moment))
    problem = _entity_problem(eid, etype, row.get(SERVICE_PATH))
    if problem is not None:
        return Unreadable(meta.name, _shown(eid), iso(moment), problem)
    present = []
    for col, (name, ngsi_type) in meta.attrs.items():
        stored = row.get(col)
        if stored is None:
            continue  # the notification did not carry it (or the reader refused the cell)
        sample = _sample(name, ngsi_type, lambda s=stored, t=ngsi_type: ngsi_value(s, t, dialect), where, dropped)
        if sample is not None:
            present.append(sample)
    if not present:
        why = "every attribute value was left out" if dropped else "every attribute column is NULL"
        return Unreadable(meta.name, eid, iso(moment), why)
    path = normalize_service_path(row.get(SERVICE_PATH) or "/")
    return EntitySample(meta.tenant, path, eid, etype, moment, present)


def _shown(value: Any) -> str | None:
    return value[:200].encode("unicode_escape").decode("ascii") if isinstance(value, str) else None


def _entity_problem(eid: str, etype: str, path: Any) -> str | None:
    """Why the API could not name this entity (its id, type or service
    path breaks the ingest rules), or None."""
    for label, value in (("entity id", eid), ("entity type", etype)):
        if (problem := id_problem(value)) is not None:
            return f"{label} {value[:200]!r} {problem}: {ID_RULE}"
    if path is not None:
        if not isinstance(path, str):
            return f"fiware_servicepath {str(path)[:80]!r} is not text"
        normal = normalize_service_path(path or "/")
        if (problem := service_path_problem(normal)) is not None:
            return f"service path {path[:200]!r} {problem}: {SERVICE_PATH_RULE}"
    return None


def _sample(name: str, ngsi_type: str | None, value, where: tuple, dropped: list[Dropped]) -> AttrSample | None:
    """The stored form of one value (``value()`` gives it), or None after
    adding to ``dropped`` why no backend could store it."""
    try:
        sample = attr_sample(name, ngsi_type, value(), None)
    except (ParseError, ValueError, TypeError, OverflowError) as exc:
        reason = getattr(exc, "description", None) or str(exc) or type(exc).__name__
        dropped.append(Dropped(name, _shown(where[1]) or "?", where[2], reason[:200]))
        return None
    if _holds_nul(sample):
        dropped.append(Dropped(name, _shown(where[1]) or "?", where[2], f"the value holds a NUL; {NUL_RULE}"))
        return None
    return sample


def _holds_nul(sample: AttrSample) -> bool:
    if "\0" in (sample.txt or "") or "\0" in (sample.ngsi_type or ""):
        return True
    js = sample.js
    return js is not None and nul_path(js.encode(), json.loads(js)) is not None


def _has_values(meta: TableMeta, row: Mapping[str, Any]) -> bool:
    return any(row.get(col) is not None for col in meta.attrs)


def _from_original(
    meta: TableMeta, row: Mapping[str, Any], failed_at: datetime, dropped: list[Dropped]
) -> EntitySample | Unreadable:
    """A failed batch's row: the entity QuantumLeap received, at its own time index."""
    where = (meta.name, _shown(row.get(ID)), iso(failed_at))
    wrapper = _json(row[ORIGINAL_ENTITY])
    entity = _json(wrapper.get("data")) if isinstance(wrapper, dict) else None
    if not isinstance(entity, dict) or not isinstance(entity.get("id"), str):
        return Unreadable(*where, "failed-batch row whose original entity cannot be parsed")
    moment = to_datetime(entity.get(TIME_INDEX)) or failed_at
    etype = entity.get("type") if isinstance(entity.get("type"), str) else row.get(TYPE)
    problem = _entity_problem(entity["id"], str(etype), row.get(SERVICE_PATH))
    if problem is not None:
        return Unreadable(*where, problem)
    at = (meta.name, entity["id"], iso(moment))
    attrs = []
    for name, attr in entity.items():
        if name in _ENTITY_KEYS:
            continue
        if (problem := name_problem(name)) is not None:
            dropped.append(Dropped(name[:200], _shown(entity["id"]) or "?", at[2], f"name {problem}: {RULE}"))
            continue
        if isinstance(attr, dict) and ("value" in attr or "object" in attr):
            value = attr["value"] if "value" in attr else attr["object"]
            declared = attr.get("type") if isinstance(attr.get("type"), str) else None
            sample = _sample(name, declared, lambda v=value: v, at, dropped)
        else:
            sample = _sample(name, None, lambda v=attr: v, at, dropped)
        if sample is not None:
            attrs.append(sample)
    if not attrs:
        return Unreadable(*where, "failed-batch row whose original entity has no attribute to import")
    path = normalize_service_path(row.get(SERVICE_PATH) or "/")
    return EntitySample(meta.tenant, path, entity["id"], str(etype), moment, attrs)


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
    return plain_value(stored)


def plain_value(value: Any, depth: int = 0) -> Any:
    """A driver's value as JSON data: what a column of any type gives
    (``numeric`` → a number, ``interval`` → ISO 8601 duration, ``bytea`` →
    base64, ``uuid``, ``inet``, ranges, ``money`` → their text, arrays →
    lists), so that no column type stops an import."""
    kind = type(value)
    if value is None or kind in (str, bool, int):
        return value
    if kind is float:
        return value if math.isfinite(value) else str(value)
    if kind is Decimal:
        if not value.is_finite():
            return str(value)
        return int(value) if value == value.to_integral_value() and abs(value) < 2**63 else float(value)
    if kind is dict:
        return {str(k): plain_value(v, depth + 1) for k, v in value.items()} if depth < 100 else str(value)
    if kind in (list, tuple):
        return [plain_value(v, depth + 1) for v in value] if depth < 100 else str(value)
    if kind in (bytes, bytearray, memoryview):
        return base64.b64encode(bytes(value)).decode("ascii")
    if kind is timedelta:
        return _duration(value)
    if kind is datetime:
        return iso(value if value.tzinfo else value.replace(tzinfo=UTC))
    if kind in (date, time):
        return value.isoformat()
    if isinstance(value, uuid.UUID | ipaddress.IPv4Address | ipaddress.IPv6Address):
        return str(value)
    return str(value)


def _duration(span: timedelta) -> str:
    """ISO 8601: ``P1DT2H3M4.5S`` (negative spans with a leading ``-``)."""
    sign = "-" if span < timedelta(0) else ""
    span = abs(span)
    hours, rest = divmod(span.seconds, 3600)
    minutes, seconds = divmod(rest, 60)
    secs = f"{seconds + span.microseconds / 1e6:g}"
    return f"{sign}P{span.days}DT{hours}H{minutes}M{secs}S"


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
