"""Temporal upsert and partial update (ETSI GS CIM 009 V1.9.1 clauses
5.6.11, 5.6.12; multi-typing clause 4.16): a write naming another type
unites the entity's types, the query and retrieve show one entity with all
of them and all its instances; the instances written before, deletions
included, stay in its history."""

from __future__ import annotations

import pytest

from tests.ngsild_fixtures import ENTITIES, H, get, ids

V = "urn:ngsi-ld:Vehicle:u1"


def instance(value, minute: int, **extra) -> dict:
    return {"type": "Property", "value": value, "observedAt": f"2024-01-01T00:{minute:02d}:00Z", **extra}


@pytest.fixture
def vehicle(client):
    body = {
        "id": V,
        "type": "Vehicle",
        "speed": [
            instance(1, 0),
            {"type": "Property", "value": "urn:ngsi-ld:null", "deletedAt": "2024-01-01T00:05:00Z"},
        ],
    }
    assert client.post(ENTITIES, json=body, headers=H).status_code == 201
    return client


def speeds(entity: dict) -> list:
    return [i["value"] for i in entity["speed"]]


def test_an_upsert_naming_another_type_unites_the_types(vehicle):
    """Clause 5.6.11 with 4.16: 204, the entity is a Vehicle and a Car, one
    entity with every instance, found by either type and by both."""
    upsert = {"id": V, "type": "Car", "speed": [instance(2, 10)], "fuel": [instance(9, 10)]}
    assert vehicle.post(ENTITIES, json=upsert, headers=H).status_code == 204
    entity = get(vehicle, path=f"{ENTITIES}/{V}").json()
    assert entity["type"] == ["Car", "Vehicle"]
    assert speeds(entity) == [1, "urn:ngsi-ld:null", 2] and [i["value"] for i in entity["fuel"]] == [9]
    for expression in ("Vehicle", "Car", "Car;Vehicle", "Bus|Car"):
        found = get(vehicle, {"type": expression}).json()
        assert [(e["id"], e["type"]) for e in found] == [(V, ["Car", "Vehicle"])], expression
        assert speeds(found[0]) == [1, "urn:ngsi-ld:null", 2], expression
    assert ids(get(vehicle, {"type": "Car;Bus"})) == []


def test_a_partial_update_naming_a_type_unites_it_too(vehicle):
    """Clause 5.6.12: an append may name types; none keeps the entity's."""
    both = {"type": ["Vehicle", "Truck"], "speed": [instance(3, 20)]}
    assert vehicle.post(f"{ENTITIES}/{V}/attrs", json=both, headers=H).status_code == 204
    assert vehicle.post(f"{ENTITIES}/{V}/attrs", json={"speed": [instance(4, 30)]}, headers=H).status_code == 204
    entity = get(vehicle, path=f"{ENTITIES}/{V}").json()
    assert entity["type"] == ["Truck", "Vehicle"] and speeds(entity) == [1, "urn:ngsi-ld:null", 3, 4]


def test_the_history_of_deleted_instances_is_kept(vehicle):
    """The deletion instance written first (deletedAt, urn:ngsi-ld:null)
    stays where it was through later upserts and updates, and reads as a
    deletion (deletedAt kept)."""
    assert (
        vehicle.post(ENTITIES, json={"id": V, "type": "Vehicle", "speed": [instance(7, 40)]}, headers=H).status_code
        == 204
    )
    assert vehicle.post(f"{ENTITIES}/{V}/attrs", json={"speed": [instance(8, 50)]}, headers=H).status_code == 204
    history = get(vehicle, path=f"{ENTITIES}/{V}").json()["speed"]
    assert speeds({"speed": history}) == [1, "urn:ngsi-ld:null", 7, 8]
    assert history[1]["deletedAt"] == "2024-01-01T00:05:00Z"
    deleted = get(vehicle, path=f"{ENTITIES}/{V}", params={"timeproperty": "deletedAt", "timerel": "after",
                                                             "timeAt": "2024-01-01T00:00:00Z"}).json()  # fmt: skip
    assert speeds(deleted) == ["urn:ngsi-ld:null"]


def test_the_quantumleap_api_sees_each_type(vehicle):
    """The NGSIv2 API keys entities by (id, type): a united entity is there
    under each type it was written with."""
    assert (
        vehicle.post(ENTITIES, json={"id": V, "type": "Car", "speed": [instance(2, 10)]}, headers=H).status_code == 204
    )
    listed = vehicle.get("/v2/entities", headers={"Fiware-Service": "fleet"}).json()
    assert sorted((e["id"], e["type"]) for e in listed) == [(V, "Car"), (V, "Vehicle")]
