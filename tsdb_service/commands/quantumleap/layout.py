"""QuantumLeap's TimescaleDB/PostgreSQL layout, written from NGSI entities.

For the import's tests and benchmark, which need QuantumLeap's tables
without running QuantumLeap: what its PostgreSQL translator stores for an
NGSIv2 entity (its documentation and ``specification/`` describe the
layout; ``rows`` says what each column means). Built from that description,
not from QuantumLeap's code:

* a schema ``mt<tenant>`` per tenant (none for the default tenant), a table
  ``et<type>`` per entity type, both lower-cased;
* ``entity_id``, ``entity_type``, ``time_index`` (``timestamptz``),
  ``fiware_servicepath``, ``__original_ngsi_entity__`` (``jsonb``),
  ``instanceid`` (a fresh URN per row), and a lower-cased column per
  attribute, typed by its NGSI type (``TYPES``);
* an index on ``time_index`` (TimescaleDB's hypertable has one) and on
  ``(entity_id, time_index)``;
* ``md_ets_metadata(table_name text primary key, entity_attrs jsonb)``
  mapping each column to ``[original name, NGSI type]``.

Geometry columns need PostGIS (``has_postgis``); values go in as EWKT.
"""

from __future__ import annotations

import json
import uuid
from collections.abc import Iterable, Sequence
from datetime import datetime
from typing import Any

from tsdb_service.commands.quantumleap.rows import (
    METADATA_TABLE,
    ORIGINAL_ENTITY,
    SERVICE_PATH,
    TENANT_PREFIX,
    TYPE_PREFIX,
)
from tsdb_service.storage.sql.dialect import quote_ident

# NGSI type → column type, as QuantumLeap's PostgreSQL translator declares them.
TYPES = {
    "Array": "jsonb",
    "Boolean": "boolean",
    "DateTime": "timestamptz",
    "ISO8601": "timestamptz",
    "Integer": "bigint",
    "Number": "float",
    "Text": "text",
    "StructuredValue": "jsonb",
    "geo:json": "geometry",
    "GeoProperty": "geometry",
    "geo:point": "geometry",
    "geo:line": "geometry",
    "geo:polygon": "geometry",
    "geo:box": "geometry",
}
_FIXED = {
    "entity_id": "text",
    "entity_type": "text",
    "time_index": "timestamptz NOT NULL",
    SERVICE_PATH: "text",
    ORIGINAL_ENTITY: "jsonb",
    "instanceid": "text",
}


def table_name(tenant: str, entity_type: str) -> str:
    """The name ``md_ets_metadata`` keeps: ``"mt<tenant>"."et<type>"`` or ``"et<type>"``."""
    table = f'"{TYPE_PREFIX}{entity_type.lower()}"'
    return f'"{TENANT_PREFIX}{tenant.lower()}".{table}' if tenant else table


def has_postgis(conn) -> bool:
    row = conn.execute("SELECT count(*) FROM pg_extension WHERE extname = 'postgis'").fetchone()
    return bool(row and row[0])


def column_type(ngsi_type: str | None, value: Any) -> str:
    """A column's type: the NGSI type's, else what the value is (QuantumLeap's fallback)."""
    if ngsi_type in TYPES:
        return "jsonb" if ngsi_type == "StructuredValue" and isinstance(value, list) else TYPES[ngsi_type]
    if isinstance(value, list | dict):
        return "jsonb"
    if isinstance(value, bool):
        return "boolean"
    if isinstance(value, int):
        return "bigint"
    if isinstance(value, float):
        return "float"
    return "text"


def write_entities(
    conn,
    tenant: str,
    entities: Sequence[tuple[dict, datetime, str]],
) -> None:
    """Store (normalized NGSIv2 entity, time index, service path) triples as
    QuantumLeap does: tables and columns created as attributes appear."""
    for entity, moment, path in entities:
        attrs = {k: v for k, v in entity.items() if k not in ("id", "type") and isinstance(v, dict)}
        name = table_name(tenant, entity["type"])
        described = _ensure(conn, tenant, entity["type"], attrs)
        row: dict[str, Any] = {
            "entity_id": entity["id"],
            "entity_type": entity["type"],
            "time_index": moment,
            SERVICE_PATH: path,
            "instanceid": f"urn:ngsi-ld:{uuid.uuid4()}",
        }
        for attr, body in attrs.items():
            row[attr.lower()] = column_value(described[attr.lower()][1], body.get("value"), body.get("type"))
        insert_rows(conn, name, [row])


def column_value(col_type: str, value: Any, ngsi_type: Any = None) -> Any:
    """What a column of ``col_type`` holds for an NGSI value of ``ngsi_type``
    (None: does not fit)."""
    if value is None:
        return None
    if col_type == "jsonb":
        return json.dumps(value)
    if col_type == "geometry":
        return _ewkt(value, str(ngsi_type or "").lower())
    if col_type == "float":
        return float(value) if isinstance(value, int | float) and not isinstance(value, bool) else None
    if col_type == "bigint":
        return int(value) if isinstance(value, int) and not isinstance(value, bool) else None
    if col_type == "boolean":
        return value if isinstance(value, bool) else None
    return value if col_type == "timestamptz" else str(value)


def _ewkt(value: Any, ngsi_type: str) -> str | None:
    """The geometry QuantumLeap's PostGIS column holds for a value (EWKT).

    A ``geo:box`` ([bottom right, top left]) is kept as QuantumLeap keeps it:
    the closed ring top left, top right, bottom right, bottom left, which its
    reader turns back into the two corners."""
    import shapely

    from tsdb_service.geo.encodings import from_ngsi

    if ngsi_type == "geo:box" and isinstance(value, list) and len(value) == 2:
        return _box_ewkt(value)
    if ngsi_type not in {"geo:point", "geo:line", "geo:polygon"}:
        ngsi_type = "geo:point" if isinstance(value, str) else "geo:json"  # str: "lat, lon"
    geometry = from_ngsi(ngsi_type, value)
    if geometry is None:
        return None
    return "SRID=4326;" + shapely.from_geojson(geometry.geojson).wkt


def _box_ewkt(corners: list[Any]) -> str | None:
    try:
        (bottom, right), (top, left) = ([float(x) for x in str(c).split(",")] for c in corners)
    except ValueError:
        return None
    ring = [(left, top), (right, top), (right, bottom), (left, bottom), (left, top)]
    return "SRID=4326;POLYGON((" + ", ".join(f"{lon!r} {lat!r}" for lon, lat in ring) + "))"


def _ensure(conn, tenant: str, entity_type: str, attrs: dict[str, dict]) -> dict[str, tuple[str, str]]:
    """Create the schema, table and columns that are missing; the table's
    columns (lower-cased) → (original name, column type)."""
    name = table_name(tenant, entity_type)
    schema = f"{TENANT_PREFIX}{tenant.lower()}" if tenant else None
    table = f"{TYPE_PREFIX}{entity_type.lower()}"
    where = f"{quote_ident(schema)}.{quote_ident(table)}" if schema else quote_ident(table)
    conn.execute(
        f"CREATE TABLE IF NOT EXISTS {quote_ident(METADATA_TABLE)} (table_name text PRIMARY KEY, entity_attrs jsonb)"
    )
    if schema:
        conn.execute(f"CREATE SCHEMA IF NOT EXISTS {quote_ident(schema)}")
    fixed = ", ".join(f"{quote_ident(c)} {t}" for c, t in _FIXED.items())
    conn.execute(f"CREATE TABLE IF NOT EXISTS {where} ({fixed})")
    # TimescaleDB's hypertable index, and QuantumLeap's own on (entity_id, time_index).
    for index, columns in (
        (f"{table}_time_index_idx", "time_index DESC"),
        (f"ix_{table}_eid_and_tx", "entity_id, time_index DESC"),
    ):
        conn.execute(f"CREATE INDEX IF NOT EXISTS {quote_ident(index)} ON {where} ({columns})")
    row = conn.execute(
        f"SELECT entity_attrs FROM {quote_ident(METADATA_TABLE)} WHERE table_name = %s", [name]
    ).fetchone()
    meta: dict[str, list] = (
        row[0]
        if row
        else {
            "entity_type": ["type", "Text"],
            "entity_id": ["id", "Text"],
            "time_index": ["time_index", "DateTime"],
        }
    )
    for attr, body in attrs.items():
        column = attr.lower()
        ngsi_type = body.get("type") if isinstance(body.get("type"), str) else None
        col_type = column_type(ngsi_type, body.get("value"))
        conn.execute(f"ALTER TABLE {where} ADD COLUMN IF NOT EXISTS {quote_ident(column)} {col_type}")
        meta.setdefault(column, [attr, ngsi_type])
    conn.execute(
        f"INSERT INTO {quote_ident(METADATA_TABLE)} (table_name, entity_attrs) VALUES (%s, %s) "
        "ON CONFLICT (table_name) DO UPDATE SET entity_attrs = excluded.entity_attrs",
        [name, json.dumps(meta)],
    )
    types = {
        r[0]: r[1]
        for r in conn.execute(
            "SELECT column_name, udt_name FROM information_schema.columns WHERE table_schema = %s AND table_name = %s",
            [schema or "public", table],
        ).fetchall()
    }
    return {c: (meta[c][0], _udt(types.get(c, "text"))) for c in meta if c in types}


def _udt(udt: str) -> str:
    return {"float8": "float", "int8": "bigint", "bool": "boolean"}.get(udt, udt)


def insert_rows(conn, name: str, rows: Iterable[dict[str, Any]]) -> None:
    """Rows as they are (column → value) into a table named as
    ``md_ets_metadata`` names it; how the tests add QuantumLeap's odd rows."""
    where = ".".join(quote_ident(p.strip('"')) for p in name.split("."))
    for row in rows:
        columns = ", ".join(quote_ident(c) for c in row)
        marks = ", ".join(["%s"] * len(row))
        conn.execute(f"INSERT INTO {where} ({columns}) VALUES ({marks})", list(row.values()))


def copy_rows(conn, name: str, columns: Sequence[str], rows: Iterable[Sequence[Any]]) -> None:
    """Many rows at once (``COPY``), for the benchmark's large tables."""
    where = ".".join(quote_ident(p.strip('"')) for p in name.split("."))
    with conn.cursor().copy(f"COPY {where} ({', '.join(quote_ident(c) for c in columns)}) FROM STDIN") as copy:
        for row in rows:
            copy.write_row(row)
