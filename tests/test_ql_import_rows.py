"""QuantumLeap's stored rows become the entity samples their notifications made.

Unit tests of ``commands.quantumleap.rows``, no database: rows are given as
the PostgreSQL driver (psycopg) returns them from each QuantumLeap backend.
The CrateDB cases are built from CrateDB's documented types and
QuantumLeap's CrateDB translator (``geo_point`` as [lon, lat], or
``(lon,lat)`` text over the PostgreSQL protocol; ``geo_shape`` and
``object`` as JSON; timestamps as epoch milliseconds on CrateDB's HTTP
interface); no live CrateDB was run. The TimescaleDB geometry cases use
hex EWKB made by shapely, what PostGIS returns for a ``geometry`` column.
"""

from __future__ import annotations

import json
from datetime import UTC, datetime

import pytest
import shapely

from tsdb_service.commands.quantumleap.rows import (
    Dialect,
    Unreadable,
    duplicate_key,
    ngsi_value,
    row_to_entity,
    split_table_name,
    table_meta,
)
from tsdb_service.core.model import EntitySample, Kind

T = datetime(2024, 5, 1, 10, 0, 0, 123456, tzinfo=UTC)
BASE = {"entity_type": ["type", "Text"], "entity_id": ["id", "Text"], "time_index": ["time_index", "DateTime"]}


def _meta(dialect: Dialect, table: str = '"mtacme"."etroom"', **attrs):
    meta = table_meta(table, {**BASE, **attrs}, dialect)
    assert meta is not None
    return meta


def _row(**columns) -> dict:
    return {"entity_id": "Room1", "entity_type": "Room", "time_index": T, "fiware_servicepath": "/f", **columns}


def _entity(result) -> EntitySample:
    assert isinstance(result, EntitySample), result
    return result


def test_table_names_give_tenant_schema_and_type():
    assert split_table_name('"mtacme"."etroom"', Dialect.POSTGRESQL) == ("mtacme", "etroom")
    assert split_table_name('"etroom"', Dialect.POSTGRESQL) == ("public", "etroom")
    assert split_table_name('"etroom"', Dialect.CRATE) == ("doc", "etroom"), "CrateDB: no tenant is schema doc"
    assert split_table_name('"other"', Dialect.POSTGRESQL) is None, "not a QuantumLeap table"
    meta = _meta(Dialect.CRATE, '"etroom"')
    assert (meta.tenant, meta.entity_type) == ("", "room")


def test_original_names_and_types_come_back_from_the_metadata():
    meta = _meta(Dialect.POSTGRESQL, temperature=["Temperature", "Number"], on=["On", "Boolean"])
    entity = _entity(row_to_entity(meta, _row(temperature=21.5, on=True), Dialect.POSTGRESQL))
    assert (entity.tenant, entity.service_path, entity.entity_id, entity.entity_type) == ("acme", "/f", "Room1", "Room")
    assert [(a.name, a.ngsi_type, a.kind) for a in entity.attrs] == [
        ("Temperature", "Number", Kind.NUMBER),
        ("On", "Boolean", Kind.BOOLEAN),
    ]


def test_time_index_is_kept_exactly():
    meta = _meta(Dialect.POSTGRESQL, t=["t", "Number"])
    assert _entity(row_to_entity(meta, _row(t=1.0), Dialect.POSTGRESQL)).time_index == T


def test_crate_timestamps_in_milliseconds():
    meta = _meta(Dialect.CRATE, seen=["seen", "DateTime"])
    ms = 1714557600123
    entity = _entity(row_to_entity(meta, _row(time_index=ms, seen=ms), Dialect.CRATE))
    assert entity.time_index == datetime(2024, 5, 1, 10, 0, 0, 123000, tzinfo=UTC)
    assert entity.attrs[0].txt == "2024-05-01T10:00:00.123+00:00", "QuantumLeap's spelling of a DateTime"


def test_null_columns_are_absent_attributes_not_null_samples():
    meta = _meta(Dialect.POSTGRESQL, temperature=["temperature", "Number"], name=["name", "Text"])
    entity = _entity(row_to_entity(meta, _row(temperature=None, name="Kitchen"), Dialect.POSTGRESQL))
    assert [a.name for a in entity.attrs] == ["name"]


def test_a_row_with_every_attribute_null_is_reported():
    meta = _meta(Dialect.POSTGRESQL, temperature=["temperature", "Number"])
    result = row_to_entity(meta, _row(temperature=None), Dialect.POSTGRESQL)
    assert isinstance(result, Unreadable) and "NULL" in result.reason


@pytest.mark.parametrize(
    ("stored", "expected"),
    [
        ([2.1864475, 41.3763726], "41.3763726, 2.1864475"),  # CrateDB's HTTP interface
        ("(2.1864475,41.3763726)", "41.3763726, 2.1864475"),  # its PostgreSQL protocol (point)
        ({"type": "Point", "coordinates": [2.5, 41.0]}, "41.0, 2.5"),
    ],
)
def test_crate_geo_point_becomes_lat_lon_text(stored, expected):
    assert ngsi_value(stored, "geo:point", Dialect.CRATE) == expected


def test_crate_geo_shape_and_objects_are_json():
    shape = {"type": "Polygon", "coordinates": [[[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 0.0]]]}
    assert ngsi_value(shape, "geo:json", Dialect.CRATE) == shape
    assert ngsi_value(json.dumps(shape), "geo:json", Dialect.CRATE) == shape, "JSON text over the wire"
    assert ngsi_value('{"a": 1}', "StructuredValue", Dialect.CRATE) == {"a": 1}
    assert ngsi_value(["a", "b"], "Array", Dialect.CRATE) == ["a", "b"]
    assert ngsi_value("{not json", "Text", Dialect.CRATE) == "{not json", "text stays text"


def _ewkb(wkt: str) -> str:
    return shapely.to_wkb(shapely.from_wkt(wkt), hex=True, include_srid=False, flavor="extended")


def _ewkb_srid(wkt: str) -> str:
    return shapely.to_wkb(shapely.set_srid(shapely.from_wkt(wkt), 4326), hex=True, include_srid=True)


@pytest.mark.parametrize("encode", [_ewkb, _ewkb_srid])
def test_postgis_geometries_come_back_as_quantumleap_answers(encode):
    pg = Dialect.POSTGRESQL
    assert ngsi_value(encode("POINT (2.5 41.25)"), "geo:json", pg) == {"type": "Point", "coordinates": [2.5, 41.25]}
    assert ngsi_value(encode("POINT (2.1864475 41.3763726)"), "geo:point", pg) == "41.3763726, 2.1864475"
    assert ngsi_value(encode("LINESTRING (2 1, 4 3)"), "geo:line", pg) == ["1.0, 2.0", "3.0, 4.0"]
    ring = "POLYGON ((0 0, 0 1, 1 0, 0 0))"
    assert ngsi_value(encode(ring), "geo:polygon", pg) == ["0.0, 0.0", "1.0, 0.0", "0.0, 1.0", "0.0, 0.0"]
    # a box [p0, p1] is stored as the ring [p1, (p1.lat, p0.lon), p0, (p0.lat, p1.lon), p1]
    box = "POLYGON ((-8.65 40.63, -8.66 40.63, -8.66 40.64, -8.65 40.64, -8.65 40.63))"
    assert ngsi_value(encode(box), "geo:box", pg) == ["40.64, -8.66", "40.63, -8.65"]


def test_a_geometry_sample_is_stored_as_geo():
    meta = _meta(Dialect.POSTGRESQL, location=["location", "geo:point"])
    entity = _entity(row_to_entity(meta, _row(location=_ewkb("POINT (2.5 41.25)")), Dialect.POSTGRESQL))
    attr = entity.attrs[0]
    assert (attr.kind, attr.js, attr.geo is not None) == (Kind.GEO, '"41.25, 2.5"', True)


def _failed(data, dialect: Dialect) -> dict:
    """A row QuantumLeap wrote after a failed batch: only the original entity."""
    wrapper = {"data": data, "failedBatchID": "f00", "error": "ProgrammingError(...)"}
    return {
        "entity_id": "Room1",
        "entity_type": "Room",
        "time_index": T,
        "fiware_servicepath": None,
        "__original_ngsi_entity__": wrapper,
    }


ORIGINAL = {
    "id": "Room1",
    "type": "Room",
    "time_index": "2024-04-30T08:00:00.000+00:00",
    "temperature": {"type": "Number", "value": 19.5},
    "note": {"type": "Text", "value": "x"},
}


@pytest.mark.parametrize(
    ("dialect", "data"),
    [(Dialect.POSTGRESQL, ORIGINAL), (Dialect.CRATE, json.dumps(ORIGINAL))],  # CrateDB keeps data as JSON text
)
def test_failed_batch_rows_are_imported_from_their_original_entity(dialect, data):
    meta = _meta(dialect, temperature=["temperature", "Number"])
    entity = _entity(row_to_entity(meta, _failed(data, dialect), dialect))
    assert entity.time_index == datetime(2024, 4, 30, 8, tzinfo=UTC), "the entity's own time index"
    assert entity.service_path == "/"
    assert [(a.name, a.num, a.txt) for a in entity.attrs] == [("temperature", 19.5, None), ("note", None, "x")]


def test_a_failed_batch_row_that_cannot_be_parsed_is_reported():
    meta = _meta(Dialect.POSTGRESQL, temperature=["temperature", "Number"])
    result = row_to_entity(meta, _failed("{truncated", Dialect.POSTGRESQL), Dialect.POSTGRESQL)
    assert isinstance(result, Unreadable) and "cannot be parsed" in result.reason


def test_duplicates_differ_only_in_instanceid():
    meta = _meta(Dialect.POSTGRESQL, temperature=["temperature", "Number"])
    one = _entity(row_to_entity(meta, _row(temperature=1.0, instanceid="urn:a"), Dialect.POSTGRESQL))
    two = _entity(row_to_entity(meta, _row(temperature=1.0, instanceid="urn:b"), Dialect.POSTGRESQL))
    other = _entity(row_to_entity(meta, _row(temperature=2.0, instanceid="urn:c"), Dialect.POSTGRESQL))
    assert duplicate_key(one) == duplicate_key(two) != duplicate_key(other)
