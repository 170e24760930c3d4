"""The NGSI-LD temporal write endpoints (ETSI GS CIM 009 clauses 5.6.11-
5.6.15, 6.18-6.22): status codes, what is stored, errors as ProblemDetails,
and that the NGSIv2/QuantumLeap API sees the written data."""

from __future__ import annotations

from datetime import datetime

import pytest

from tsdb_service.core.model import Kind, instance_urn
from tsdb_service.core.query import EntityFilter, Scope
from tsdb_service.read.requests import InstancesRead, SeriesSelect

BASE = "/ngsi-ld/v1/temporal/entities"
VEHICLE = "urn:ngsi-ld:Vehicle:B9211"
JSON = {"Content-Type": "application/json"}
ERRORS = "https://uri.etsi.org/ngsi-ld/errors/"


def temporal_vehicle(**extra) -> dict:
    """A temporal representation in the spirit of the spec's annex C.5."""
    return {
        "id": VEHICLE,
        "type": "Vehicle",
        "speed": [
            {"type": "Property", "value": 120, "observedAt": "2018-08-01T12:03:00Z", "unitCode": "KMH"},
            {"type": "Property", "value": 80, "observedAt": "2018-08-01T12:05:00Z", "unitCode": "KMH"},
        ],
        "fuelLevel": [{"type": "Property", "value": 67, "observedAt": "2018-08-01T12:03:00Z"}],
        **extra,
    }


def stored(client, tenant="", eid=VEHICLE):
    q = client.app.state.store.querier()
    refs = {r.sid: r for r in q.series(SeriesSelect(Scope(tenant), EntityFilter(ids=(eid,))))}
    return [(refs[r.sid].ld_attr, r) for r in q.temporal_instances(InstancesRead(list(refs)))]


def problem(response, status: int, ld_type: str) -> dict:
    assert response.status_code == status, response.text
    assert response.headers["content-type"].startswith("application/json")
    body = response.json()
    assert body["type"] == ERRORS + ld_type and body["status"] == status
    assert body["title"] and body["detail"]
    return body


def create(client, body=None, headers=None):
    return client.post(BASE, json=body or temporal_vehicle(), headers={**JSON, **(headers or {})})


def test_create_then_upsert(client):
    response = create(client)
    assert response.status_code == 201, response.text
    assert response.headers["location"] == f"{BASE}/{VEHICLE}"
    rows = stored(client)
    assert sorted((name, r.num) for name, r in rows) == [("fuelLevel", 67), ("speed", 80), ("speed", 120)]
    speed = [r for name, r in rows if name == "speed"]
    assert [r.observed_at for r in speed] == [datetime(2018, 8, 1, 12, 3), datetime(2018, 8, 1, 12, 5)]
    assert all(r.created_at is not None and r.created_at == r.modified_at for _, r in rows)
    assert '"unitCode":"KMH"' in speed[0].md
    # The same entity again: its instances are added (204).
    again = create(
        client,
        {
            "id": VEHICLE,
            "type": "Vehicle",
            "speed": {"type": "Property", "value": 90, "observedAt": "2018-08-01T12:07:00Z"},
        },
    )
    assert again.status_code == 204, again.text
    assert [r.num for name, r in stored(client) if name == "speed"] == [120, 80, 90]


def test_system_members_sent_by_the_client_are_ignored(client):
    body = {
        "id": VEHICLE,
        "type": "Vehicle",
        "speed": [
            {
                "type": "Property",
                "value": 1,
                "observedAt": "2018-08-01T12:00:00Z",
                "createdAt": "2000-01-01T00:00:00Z",
                "modifiedAt": "2000-01-01T00:00:00Z",
                "instanceId": "urn:ngsi-ld:attribute:instance:0000000000000001",
            }
        ],
    }
    assert create(client, body).status_code == 201
    [(_, row)] = stored(client)
    assert row.created_at.year > 2000 and row.md == '{"observedAt":"2018-08-01T12:00:00Z"}'


def test_written_instances_are_seen_by_the_v2_api(client):
    assert create(client).status_code == 201
    v2 = client.get(f"/v2/entities/{VEHICLE}", params={"type": "Vehicle"})
    assert v2.status_code == 200, v2.text
    body = v2.json()
    assert body["index"] == ["2018-08-01T12:03:00.000+00:00", "2018-08-01T12:05:00.000+00:00"]
    attrs = {a["attrName"]: a["values"] for a in body["attributes"]}
    # Instances observed at the same time share one NGSIv2 row.
    assert attrs == {"fuelLevel": [67, None], "speed": [120, 80]}


def test_ld_json_body_carries_its_context(client):
    body = {**temporal_vehicle(), "@context": "https://uri.etsi.org/ngsi-ld/v1/ngsi-ld-core-context.jsonld"}
    response = client.post(BASE, json=body, headers={"Content-Type": "application/ld+json"})
    assert response.status_code == 201, response.text
    problem(
        client.post(BASE, json=temporal_vehicle(), headers={"Content-Type": "application/ld+json"}),
        400,
        "BadRequestData",
    )
    problem(client.post(BASE, json=body, headers=JSON), 400, "BadRequestData")


def test_datasets_and_relationships(client):
    body = {
        "id": VEHICLE,
        "type": "Vehicle",
        "speed": [
            {
                "type": "Property",
                "value": 55,
                "datasetId": "urn:ngsi-ld:Dataset:gps",
                "observedAt": "2018-08-01T12:03:00Z",
            },
            {"type": "Property", "value": 56, "observedAt": "2018-08-01T12:03:00Z"},
        ],
        "isParked": [
            {
                "type": "Relationship",
                "object": "urn:ngsi-ld:OffStreetParking:Downtown1",
                "observedAt": "2018-08-01T12:03:00Z",
            }
        ],
    }
    assert create(client, body).status_code == 201
    rows = sorted((name, r.dataset_id or "", r.kind, r.num, r.txt) for name, r in stored(client))
    assert rows == [
        ("isParked", "", Kind.RELATIONSHIP, None, "urn:ngsi-ld:OffStreetParking:Downtown1"),
        ("speed", "", Kind.INTEGER, 56, None),
        ("speed", "urn:ngsi-ld:Dataset:gps", Kind.INTEGER, 55, None),
    ]


def test_tenants_are_kept_apart(client):
    assert create(client, headers={"NGSILD-Tenant": "Fleet"}).status_code == 201
    assert stored(client) == []
    assert len(stored(client, tenant="fleet")) == 3
    response = client.get(f"/v2/entities/{VEHICLE}/attrs/speed", headers={"Fiware-Service": "fleet"})
    assert response.status_code == 200 and response.json()["values"] == [120, 80]


@pytest.mark.parametrize(
    "body, ld_type",
    [
        ({"type": "Vehicle", "speed": [{"type": "Property", "value": 1}]}, "BadRequestData"),
        ({"id": "not a uri", "type": "Vehicle", "speed": [{"type": "Property", "value": 1}]}, "BadRequestData"),
        ({"id": VEHICLE, "speed": [{"type": "Property", "value": 1}]}, "BadRequestData"),
        ({"id": VEHICLE, "type": 5, "speed": [{"type": "Property", "value": 1}]}, "BadRequestData"),
        ({"id": VEHICLE, "type": "Vehicle", "speed": [5]}, "BadRequestData"),
        ({"id": VEHICLE, "type": "Vehicle", "speed": [{"unitCode": "KMH"}]}, "BadRequestData"),
        ({"id": VEHICLE, "type": "Vehicle", "sp eed": [{"type": "Property", "value": 1}]}, "BadRequestData"),
        ({"id": VEHICLE, "type": "Vehicle"}, "BadRequestData"),
        (
            {"id": VEHICLE, "type": "Vehicle", "speed": [{"type": "Property", "value": 1, "datasetId": 5}]},
            "BadRequestData",
        ),
    ],
)
def test_create_refuses_bad_bodies(client, body, ld_type):
    problem(create(client, body), 400, ld_type)
    assert stored(client) == []


def test_create_refuses_what_is_not_json(client):
    problem(client.post(BASE, content=b"{nope", headers=JSON), 400, "InvalidRequest")
    problem(client.post(BASE, content=b"[1]", headers=JSON), 400, "InvalidRequest")
    problem(client.post(BASE, content=b"{}", headers={"Content-Type": "text/plain"}), 415, "InvalidRequest")
    problem(create(client, headers={"NGSILD-Tenant": "no-dashes"}), 400, "BadRequestData")


def test_append_instances(client):
    assert create(client).status_code == 201
    response = client.post(
        f"{BASE}/{VEHICLE}/attrs",
        headers=JSON,
        json={
            "speed": [{"type": "Property", "value": 70, "observedAt": "2018-08-01T12:09:00Z"}],
            "brandName": {"type": "Property", "value": "Volvo", "observedAt": "2018-08-01T12:09:00Z"},
        },
    )
    assert response.status_code == 204, response.text
    rows = stored(client)
    assert [r.num for name, r in rows if name == "speed"] == [120, 80, 70]
    assert [r.txt for name, r in rows if name == "brandName"] == ["Volvo"]


def test_append_errors(client):
    body = {"speed": [{"type": "Property", "value": 70}]}
    problem(client.post(f"{BASE}/urn:ngsi-ld:Vehicle:none/attrs", headers=JSON, json=body), 404, "ResourceNotFound")
    assert create(client).status_code == 201
    problem(client.post(f"{BASE}/{VEHICLE}/attrs", headers=JSON, json={}), 400, "BadRequestData")
    problem(
        client.post(f"{BASE}/{VEHICLE}/attrs", headers=JSON, json={"id": "urn:x:other", **body}), 400, "BadRequestData"
    )
    problem(
        client.post(f"{BASE}/{VEHICLE}/attrs", headers={**JSON, "NGSILD-Tenant": "nobody"}, json=body),
        404,
        "NonexistentTenant",
    )


def test_delete_entity(client):
    assert create(client).status_code == 201
    assert client.delete(f"{BASE}/{VEHICLE}").status_code == 204
    assert stored(client) == []
    assert client.get(f"/v2/entities/{VEHICLE}/attrs/speed").json() == []
    problem(client.delete(f"{BASE}/{VEHICLE}"), 404, "ResourceNotFound")
    # Created again afterwards: a new temporal representation (201).
    assert create(client).status_code == 201


def test_delete_attribute_default_dataset_and_all(client):
    body = {
        "id": VEHICLE,
        "type": "Vehicle",
        "speed": [
            {"type": "Property", "value": 1, "observedAt": "2018-08-01T12:00:00Z"},
            {"type": "Property", "value": 2, "datasetId": "urn:ds:a", "observedAt": "2018-08-01T12:00:00Z"},
            {"type": "Property", "value": 3, "datasetId": "urn:ds:b", "observedAt": "2018-08-01T12:00:00Z"},
        ],
        "fuelLevel": [{"type": "Property", "value": 9}],
    }
    assert create(client, body).status_code == 201

    def speeds():
        return sorted(r.num for name, r in stored(client) if name == "speed")

    assert client.delete(f"{BASE}/{VEHICLE}/attrs/speed").status_code == 204
    assert speeds() == [2, 3]
    problem(client.delete(f"{BASE}/{VEHICLE}/attrs/speed"), 404, "ResourceNotFound")
    assert client.delete(f"{BASE}/{VEHICLE}/attrs/speed", params={"datasetId": "urn:ds:a"}).status_code == 204
    assert speeds() == [3]
    assert client.delete(f"{BASE}/{VEHICLE}/attrs/speed", params={"deleteAll": "true"}).status_code == 204
    assert speeds() == []
    assert [name for name, _ in stored(client)] == ["fuelLevel"]
    problem(client.delete(f"{BASE}/{VEHICLE}/attrs/nothing"), 404, "ResourceNotFound")
    problem(client.delete(f"{BASE}/{VEHICLE}/attrs/fuelLevel", params={"deleteAll": "maybe"}), 400, "BadRequestData")


def test_patch_and_delete_one_instance(client):
    assert create(client).status_code == 201
    first, second = [r for name, r in stored(client) if name == "speed"]
    url = f"{BASE}/{VEHICLE}/attrs/speed/{instance_urn(first.iid)}"
    response = client.patch(url, headers=JSON, json={"speed": {"type": "Property", "value": 121, "unitCode": "KMH"}})
    assert response.status_code == 204, response.text
    patched, unchanged = [r for name, r in stored(client) if name == "speed"]
    assert (patched.iid, patched.num, patched.observed_at) == (first.iid, 121, first.observed_at)
    assert patched.modified_at > first.modified_at and patched.created_at == first.created_at
    assert unchanged == second
    # The NGSIv2 API sees the new value at the same row time.
    v2 = client.get(f"/v2/entities/{VEHICLE}/attrs/speed").json()
    assert v2["values"] == [121, 80]
    # observedAt may change too.
    body = {"type": "Property", "value": 122, "observedAt": "2018-08-01T12:04:00Z"}
    assert client.patch(url, headers=JSON, json=body).status_code == 204
    [patched] = [r for name, r in stored(client) if name == "speed" and r.iid == first.iid]
    assert (patched.num, patched.observed_at) == (122, datetime(2018, 8, 1, 12, 4))

    assert client.delete(url).status_code == 204
    assert [r.iid for name, r in stored(client) if name == "speed"] == [second.iid]
    problem(client.delete(url), 404, "ResourceNotFound")
    problem(client.patch(url, headers=JSON, json=body), 404, "ResourceNotFound")


def test_instance_errors(client):
    assert create(client).status_code == 201
    speed = next(r for name, r in stored(client) if name == "speed")
    fuel = next(r for name, r in stored(client) if name == "fuelLevel")
    body = {"type": "Property", "value": 1}
    problem(client.delete(f"{BASE}/{VEHICLE}/attrs/speed/urn:x:1"), 404, "ResourceNotFound")
    # An instance of another attribute is not this attribute's.
    problem(client.delete(f"{BASE}/{VEHICLE}/attrs/speed/{instance_urn(fuel.iid)}"), 404, "ResourceNotFound")
    url = f"{BASE}/{VEHICLE}/attrs/speed/{instance_urn(speed.iid)}"
    problem(client.patch(url, headers=JSON, json={"speed": [body, body]}), 400, "BadRequestData")
    problem(client.patch(url, headers=JSON, json={"speed": 5}), 400, "BadRequestData")
    problem(client.patch(url, headers=JSON, json={**body, "datasetId": "urn:ds:x"}), 400, "BadRequestData")
    problem(client.patch(url, headers=JSON, content=b"nope"), 400, "InvalidRequest")
    assert [r.num for name, r in stored(client) if name == "speed"] == [120, 80]


def test_instance_ids_survive_compaction_for_writes(client):
    assert create(client).status_code == 201
    before = {(name, r.num): r.iid for name, r in stored(client)}
    store = client.app.state.store
    if hasattr(store, "compact"):
        store.compact(full=True)
    assert {(name, r.num): r.iid for name, r in stored(client)} == before
    url = f"{BASE}/{VEHICLE}/attrs/speed/{instance_urn(before[('speed', 80)])}"
    assert client.delete(url).status_code == 204
    assert sorted(before) == sorted([*((name, r.num) for name, r in stored(client)), ("speed", 80)])


def test_ld_paths_answer_problem_details(client):
    problem(client.get("/ngsi-ld/v1/no-such-thing"), 404, "ResourceNotFound")
    response = client.put(f"{BASE}/{VEHICLE}", json={})
    problem(response, 405, "OperationNotSupported")
    assert "DELETE" in response.headers["allow"]
    # The NGSIv2 API keeps its own error shape.
    assert set(client.get("/v2/no-such-thing").json()) == {"error", "description"}


def test_deletion_instances_from_notifications_and_writes_mix(client):
    """A notified deletion and written instances are one history."""
    assert create(client).status_code == 201
    notification = {
        "type": "Notification",
        "data": [{"id": VEHICLE, "type": "Vehicle", "deletedAt": "2018-08-02T00:00:00Z"}],
    }
    assert client.post("/ngsi-ld/v1/notify", json=notification, headers=JSON).status_code == 200
    deleted = [(name, r.deleted_at) for name, r in stored(client) if r.deleted_at is not None]
    assert sorted(deleted) == [("fuelLevel", datetime(2018, 8, 2)), ("speed", datetime(2018, 8, 2))]
