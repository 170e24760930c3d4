"""Requests V1.9.1 refuses (400 BadRequestData, not 200, 404 or 422) where
the main suite does not look, on the temporal API's query, retrieve and
``Query`` body alike; and ``csf``, which selects among registrations this
service has none of."""

from __future__ import annotations

import pytest

from tests.ngsild_fixtures import ENTITIES, H, error_type, get, ids

V = "urn:ngsi-ld:Vehicle:v1"
QUERY = "/ngsi-ld/v1/temporal/entityOperations/query"


@pytest.fixture
def vehicle(client):
    body = {
        "id": V,
        "type": "Vehicle",
        "speed": [{"type": "Property", "value": 1, "observedAt": "2024-01-01T00:00:00Z"}],
    }
    assert client.post(ENTITIES, json=body, headers=H).status_code == 201
    return client


def bad(response) -> None:
    assert response.status_code == 400, response.text
    assert error_type(response) == "BadRequestData", response.text


@pytest.mark.parametrize("attrs", ["createdAt", "createdAt,modifiedAt", "observedAt", "id,type"])
def test_attrs_naming_only_system_members_is_bad_request_data(vehicle, attrs):
    """Clauses 4.8, 5.2.2: createdAt and its kin are members the system
    keeps, no attribute: an attrs naming only them asks for nothing."""
    bad(get(vehicle, {"type": "Vehicle", "attrs": attrs}, status=400))
    bad(get(vehicle, path=f"{ENTITIES}/{V}", params={"attrs": attrs}, status=400))
    bad(vehicle.post(QUERY, json={"type": "Query", "entities": [{"type": "Vehicle"}], "attrs": [attrs]}, headers=H))
    assert ids(get(vehicle, {"type": "Vehicle", "attrs": f"speed,{attrs}"})) == [V]


@pytest.mark.parametrize("params", [{"pick": "owner{name}"}, {"omit": "owner{name}"}, {"attrs": "owner{name}"}])
def test_linked_entity_projection_is_bad_request_data(vehicle, params):
    """The temporal API has no linked-entity retrieval (V1.9.1 retrieves linked entities on the core API)."""
    bad(get(vehicle, {"type": "Vehicle", **params}, status=400))
    bad(get(vehicle, path=f"{ENTITIES}/{V}", params=params, status=400))


def test_an_id_that_is_no_uri_is_bad_request_data(vehicle, notify):
    """Clause 4.5.1: entity ids are URIs; one no stored entity has that is
    none is a 400 on the query (the retrieve already does it). NGSIv2 data
    keeps its ids, so a stored one is found whatever it is."""
    bad(get(vehicle, {"type": "Vehicle", "id": "not a uri"}, status=400))
    bad(get(vehicle, {"type": "Vehicle", "id": f"{V},plainId"}, status=400))
    body = {"type": "Query", "entities": [{"id": "plainId", "type": "Vehicle"}]}
    bad(vehicle.post(QUERY, json=body, headers=H))
    room = {"id": "Room1", "type": "Room", "temperature": {"type": "Number", "value": 21}}
    notify(vehicle, {"subscriptionId": "s", "data": [room]}, {"Fiware-Service": "fleet"})
    assert ids(get(vehicle, {"type": "Room", "id": "Room1"})) == ["Room1"]


@pytest.mark.parametrize("csf", ["((", "endpoint==", "a==1;;b"])
def test_an_invalid_csf_is_bad_request_data(vehicle, csf):
    """csf (clause 4.9's grammar over registration members) that is none: 400."""
    bad(get(vehicle, {"type": "Vehicle", "csf": csf}, status=400))
    bad(get(vehicle, path=f"{ENTITIES}/{V}", params={"csf": csf}, status=400))
    bad(vehicle.post(QUERY, json={"type": "Query", "entities": [{"type": "Vehicle"}], "csf": csf}, headers=H))


def test_a_valid_csf_selects_no_registration_here(vehicle):
    """There are no registrations here, so the answer is the local history."""
    assert ids(get(vehicle, {"type": "Vehicle", "csf": 'endpoint=="http://x.org"'})) == [V]


@pytest.mark.parametrize("member", ["observedAt", "deletedAt"])
@pytest.mark.parametrize("moment", ["2024-01-01T12:00:00+02:00", "2024-01-01T12:00:00-05:30"])
def test_a_datetime_with_a_non_utc_offset_is_refused_on_a_write(vehicle, member, moment):
    """Clause 4.6.3: NGSI-LD DateTimes are UTC; a write naming another
    offset is a 400 (nothing stored), not moved to UTC quietly."""
    instance = {"type": "Property", "value": 2, member: moment}
    if member == "deletedAt":
        instance["value"] = "urn:ngsi-ld:null"
    fresh = "urn:ngsi-ld:Vehicle:utc"
    bad(vehicle.post(ENTITIES, json={"id": fresh, "type": "Vehicle", "speed": [instance]}, headers=H))
    bad(vehicle.post(f"{ENTITIES}/{V}/attrs", json={"speed": [instance]}, headers=H))
    assert get(vehicle, path=f"{ENTITIES}/{fresh}", status=404)
    assert len(get(vehicle, path=f"{ENTITIES}/{V}").json()["speed"]) == 1
    utc = {"type": "Property", "value": 3, "observedAt": "2024-01-01T12:00:00+00:00"}
    assert vehicle.post(f"{ENTITIES}/{V}/attrs", json={"speed": [utc]}, headers=H).status_code == 204
