"""Recorded notifications (tests/payloads) are stored and read back exactly.

Each payload is what Orion or Orion-LD sends, headers included: NGSIv1
attributes told apart by ID metadata, NGSI-LD in each attribute format, and
GeoJSON notifications. Every expected value must come back from the entity
endpoint and from the one-attribute endpoint, by the stored name.
"""

from __future__ import annotations

import json
from datetime import UTC, datetime
from pathlib import Path
from urllib.parse import quote

import orjson
import pytest

from tsdb_service.core.errors import ParseError
from tsdb_service.parse import parse_notification

PAYLOADS = Path(__file__).parent / "payloads"
STORED = sorted(p for p in PAYLOADS.glob("*/*.json") if "entity" in json.loads(p.read_text())["expect"])
NOW = datetime(2024, 6, 1, tzinfo=UTC)


def load(path: Path) -> dict:
    return json.loads(path.read_text())


def raw_body(record: dict) -> bytes:
    return orjson.dumps(record["body"]) if "body" in record else record["bodyText"].encode()


def tenant_headers(record: dict) -> dict:
    headers = record["headers"]
    return {"Fiware-Service": headers.get("Ngsild-Tenant") or headers.get("Fiware-Service") or ""}


@pytest.fixture(scope="module")
def loaded(client_factory, store_url_factory):
    with client_factory(store_url_factory("payloads")) as client:
        for path in STORED:
            record = load(path)
            response = client.post("/v2/notify", content=raw_body(record), headers=record["headers"])
            assert response.status_code == 200, (path.name, response.text)
        yield client


@pytest.mark.parametrize("path", STORED, ids=lambda p: f"{p.parent.name}/{p.stem}")
def test_read_back_exactly(loaded, path):
    record = load(path)
    expect = record["expect"]
    entity = loaded.get(f"/v2/entities/{quote(expect['entity'])}", headers=tenant_headers(record)).json()
    got = {a["attrName"]: a["values"][-1] for a in entity["attributes"]}
    for name, value in expect["values"].items():
        assert got[name] == value, (name, got)
    if "type" in expect:
        assert entity["type"] == expect["type"]
    if "time" in expect:
        assert entity["index"] == [expect["time"]]


@pytest.mark.parametrize("path", STORED, ids=lambda p: f"{p.parent.name}/{p.stem}")
def test_each_attribute_by_its_stored_name(loaded, path):
    record = load(path)
    expect = record["expect"]
    for name, value in expect["values"].items():
        url = f"/v2/entities/{quote(expect['entity'])}/attrs/{quote(name, safe='')}"
        response = loaded.get(url, headers=tenant_headers(record))
        assert response.status_code == 200, (name, response.text)
        assert response.json()["values"] == [value]


def test_geojson_features_are_entities_with_geometry(loaded):
    record = load(PAYLOADS / "geojson" / "simplified.json")
    listed = loaded.get("/v2/entities", params={"type": "Drone"}, headers=tenant_headers(record)).json()
    assert {"urn:ngsi-ld:Drone:simplified", "urn:ngsi-ld:Drone:parked"} <= {e["id"] for e in listed}
    near = loaded.get(
        "/v2/entities",
        headers=tenant_headers(record),
        params={"type": "Drone", "georel": "near;maxDistance:100", "geometry": "point", "coords": "40.4168,-3.7038"},
    ).json()
    assert "urn:ngsi-ld:Drone:simplified" in {e["id"] for e in near}
    assert "urn:ngsi-ld:Drone:parked" not in {e["id"] for e in near}


def test_v1_id_metadata_is_kept_in_metadata():
    record = load(PAYLOADS / "ngsiv1" / "attributes_with_id.json")
    [entity] = parse_notification(raw_body(record), record["headers"], received_at=NOW)
    by_name = {a.name: a for a in entity.attrs}
    assert json.loads(by_name["temperature~ground"].md)["ID"] == {"type": "string", "value": "ground"}
    assert json.loads(by_name["temperature~roof"].md)["ID"]["value"] == "roof"
    assert by_name["humidity"].md is None


def test_v1_same_name_without_distinct_id_is_refused(client):
    body = {
        "contextResponses": [
            {
                "contextElement": {
                    "id": "G",
                    "type": "T",
                    "isPattern": "false",
                    "attributes": [
                        {
                            "name": "t",
                            "type": "float",
                            "value": "1",
                            "metadatas": [{"name": "ID", "type": "string", "value": "a"}],
                        },
                        {
                            "name": "t",
                            "type": "float",
                            "value": "2",
                            "metadatas": [{"name": "ID", "type": "string", "value": "a"}],
                        },
                    ],
                },
                "statusCode": {"code": "200", "reasonPhrase": "OK"},
            }
        ]
    }
    response = client.post("/v2/notify", json=body, headers={"Fiware-Service": "v1dup"})
    assert response.status_code == 400
    assert "'t~a' appears twice" in response.json()["description"]
    [kept] = client.get("/v2/notify/rejected", headers={"Fiware-Service": "v1dup"}).json()
    assert orjson.loads(kept["body"]) == body


def ld_notification(entity: dict) -> dict:
    return {
        "id": "urn:ngsi-ld:Notification:1",
        "type": "Notification",
        "subscriptionId": "urn:s",
        "notifiedAt": "2024-05-01T10:00:00Z",
        "data": [entity],
    }


ENTITY = {
    "id": "urn:E",
    "type": "T",
    "when": {"type": "DateTime", "value": "2024-05-01T09:00:00Z"},
    "size": {"value": 5, "unit": "m"},
}


@pytest.mark.parametrize(
    "headers",
    [
        {"Ngsild-Attribute-Format": "Simplified"},
        {"Ngsild-Attribute-Format": "SIMPLIFIED"},
        {"Ngsild-Attribute-Format": " simplified "},
        {"Ngsiv2-AttrsFormat": "keyValues"},
        {"Ngsild-Attribute-Format": "Simplified", "Ngsiv2-AttrsFormat": "normalized"},
    ],
)
def test_simplified_objects_are_values(headers):
    [entity] = parse_notification(orjson.dumps(ld_notification(ENTITY)), headers, received_at=NOW)
    values = {a.name: json.loads(a.js) for a in entity.attrs}
    assert values == {"when": ENTITY["when"], "size": ENTITY["size"]}
    assert all(a.md is None for a in entity.attrs)


@pytest.mark.parametrize(
    "headers", [{}, {"Ngsild-Attribute-Format": "Concise"}, {"Ngsild-Attribute-Format": "normalized"}]
)
def test_concise_reads_value_members(headers):
    # Without a header the body's shape decides: NGSI-LD's concise form,
    # where {"value": 5, "unit": "m"} is a Property of 5 with a sub-property.
    [entity] = parse_notification(orjson.dumps(ld_notification(ENTITY)), headers, received_at=NOW)
    size = next(a for a in entity.attrs if a.name == "size")
    assert size.num == 5 and json.loads(size.md) == {"unit": "m"}


def test_unknown_ld_attribute_format_is_refused():
    with pytest.raises(ParseError, match="Ngsild-Attribute-Format 'verbose'"):
        parse_notification(
            orjson.dumps(ld_notification(ENTITY)), {"Ngsild-Attribute-Format": "verbose"}, received_at=NOW
        )


def test_geojson_single_feature_and_geometry_without_attribute():
    # A geometry no attribute carries (e.g. a subscription's geometryProperty
    # filtered out of the attributes) is kept as "location".
    feature = {
        "id": "urn:D",
        "type": "Feature",
        "properties": {"type": "Drone", "alt": 3},
        "geometry": {"type": "Point", "coordinates": [1.0, 2.0]},
    }
    body = {"id": "urn:n", "type": "Notification", "subscriptionId": "urn:s", "data": feature}
    [entity] = parse_notification(orjson.dumps(body), {"Ngsild-Attribute-Format": "Normalized"}, received_at=NOW)
    by_name = {a.name: a for a in entity.attrs}
    assert (entity.entity_id, entity.entity_type) == ("urn:D", "Drone")
    assert json.loads(by_name["location"].js) == feature["geometry"]
    assert by_name["location"].geo is not None


@pytest.mark.parametrize(
    "data",
    [
        {"type": "FeatureCollection"},
        {"type": "FeatureCollection", "features": 5},
        {"type": "FeatureCollection", "features": [{"id": "x", "properties": 3}]},
        {"type": "FeatureCollection", "features": [7]},
    ],
)
def test_malformed_geojson_is_a_parse_error(data):
    body = {"id": "urn:n", "type": "Notification", "subscriptionId": "urn:s", "data": data}
    with pytest.raises(ParseError):
        parse_notification(orjson.dumps(body), {}, received_at=NOW)
