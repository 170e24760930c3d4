"""The state as of an instant (our extension; the spec's Snapshot resource,
optional in TS 104 175 clause 16, is an asynchronous resource to create,
poll and delete, not a read): every matched entity as it was at time t,
each attribute's latest instance at or before t with its time, in one
request.

* NGSI-LD: ``GET /ngsi-ld/v1/temporal/entities?asOf=t`` (and retrieve, and
  the Query body's query string): equal to each attribute's ``lastN=1``
  before the instant; ``q``, ``scopeQ`` and the geo-query judged on the
  state then.
* QuantumLeap API: ``POST /v2/op/query?asOf=t``: the entities in NGSIv2
  form, each attribute at its value then, with its ``dateModified``.

A fleet of robots reconstructed at the moment of an incident, on both backends.
"""

from __future__ import annotations

from datetime import UTC, datetime, timedelta

import pytest

from tests.ngsild_fixtures import ENTITIES, H, error_type, get, ids

T0 = datetime(2024, 5, 1, 10, 0, tzinfo=UTC)
ROBOTS = [f"urn:ngsi-ld:Robot:{n}" for n in range(4)]
INCIDENT = T0 + timedelta(minutes=7, seconds=30)


def at(minutes: float) -> str:
    return (T0 + timedelta(minutes=minutes)).isoformat().replace("+00:00", "Z")


def iso(moment: datetime) -> str:
    return moment.isoformat().replace("+00:00", "Z")


def fleet_member(n: int) -> dict:
    """Robot n reports its battery every minute from minute n, its mode at
    minutes 0 and 6, its position every other minute; robot 3 starts
    after the incident."""
    start = 9 if n == 3 else n
    return {
        "id": ROBOTS[n],
        "type": "Robot",
        "battery": [{"type": "Property", "value": 100 - 5 * m - n, "observedAt": at(m)} for m in range(start, 12)],
        "mode": [
            {"type": "Property", "value": "mowing" if n % 2 else "docked", "observedAt": at(max(start, 0))},
            {"type": "Property", "value": "stuck" if n == 1 else "docked", "observedAt": at(max(start, 6))},
        ],
        "location": [
            {
                "type": "GeoProperty",
                "value": {"type": "Point", "coordinates": [0.001 * m * (n + 1), 0.0]},
                "observedAt": at(m),
            }
            for m in range(start, 12, 2)
        ],
    }


@pytest.fixture
def fleet(client):
    for n in range(4):
        response = client.post(ENTITIES, json=fleet_member(n), headers=H)
        assert response.status_code == 201, response.text
    return client


def state(response) -> dict[str, dict]:
    return {e["id"]: {a: v for a, v in e.items() if a not in ("id", "type")} for e in response.json()}


def test_the_state_as_of_an_instant_is_each_attributes_last_instance_before_it(fleet):
    """asOf equals lastN=1 over timerel=before just past the instant, for
    every entity and attribute (observedAt and each instance as stored)."""
    as_of = state(get(fleet, {"type": "Robot", "asOf": iso(INCIDENT)}))
    just_after = iso(INCIDENT + timedelta(microseconds=1))
    last = state(get(fleet, {"type": "Robot", "lastN": "1", "timerel": "before", "timeAt": just_after}))
    assert as_of == last
    assert set(as_of) == set(ROBOTS[:3])  # robot 3 had no instance yet
    robot1 = as_of[ROBOTS[1]]
    assert [(i["value"], i["observedAt"]) for i in robot1["battery"]] == [(64, at(7))]
    assert [(i["value"], i["observedAt"]) for i in robot1["mode"]] == [("stuck", at(6))]
    assert robot1["location"][0]["observedAt"] == at(7)


def test_an_instance_at_the_instant_is_the_state(fleet):
    """At or before: an instance observed exactly at t is the state at t."""
    got = state(get(fleet, {"type": "Robot", "attrs": "battery", "asOf": at(7)}))
    assert [i["observedAt"] for i in got[ROBOTS[0]]["battery"]] == [at(7)]


def test_q_scope_and_geo_are_judged_on_the_state_then(fleet):
    """q holds on the state at t (a robot stuck then, not one stuck at some
    other time), the geo-query on the positions then."""
    assert ids(get(fleet, {"type": "Robot", "q": 'mode=="stuck"', "asOf": iso(INCIDENT)})) == [ROBOTS[1]]
    assert ids(get(fleet, {"type": "Robot", "q": 'mode=="mowing"', "asOf": iso(INCIDENT)})) == []
    assert ids(get(fleet, {"type": "Robot", "q": 'mode=="mowing"', "asOf": at(5)})) == [ROBOTS[1]]
    # robot n is 0.001 * m * (n + 1) degrees east of the origin at minute m (about 111 m per 0.001)
    near = {"geometry": "Point", "coordinates": "[0.0,0.0]"}
    assert ids(get(fleet, {"type": "Robot", "asOf": at(2), "georel": "near;maxDistance==300", **near})) == ROBOTS[:2]
    at_incident = {"type": "Robot", "asOf": iso(INCIDENT), "georel": "near;maxDistance==700", **near}
    assert ids(get(fleet, at_incident)) == [ROBOTS[0]]


def test_retrieve_and_representations(fleet):
    one = get(fleet, path=f"{ENTITIES}/{ROBOTS[2]}", params={"asOf": iso(INCIDENT), "attrs": "battery"}).json()
    assert [i["value"] for i in one["battery"]] == [63]
    simplified = get(fleet, {"type": "Robot", "attrs": "battery", "asOf": iso(INCIDENT), "format": "temporalValues"})
    assert simplified.json()[0]["battery"] == {"type": "Property", "values": [[65, at(7)]]}
    none_yet = get(fleet, path=f"{ENTITIES}/{ROBOTS[3]}", params={"asOf": iso(INCIDENT)}).json()
    assert none_yet == {"id": ROBOTS[3], "type": "Robot"}


@pytest.mark.parametrize(
    "clash",
    [
        {"timerel": "before", "timeAt": "2024-05-01T10:05:00Z"},
        {"lastN": "2"},
        {"firstN": "2"},
        {"offsetN": "2"},
        {"format": "aggregatedValues", "aggrMethods": "max"},
        {"asOf": "yesterday"},
    ],
)
def test_as_of_is_its_own_window(fleet, clash):
    response = get(fleet, {"type": "Robot", "asOf": iso(INCIDENT), **clash}, status=400)
    assert error_type(response) == "BadRequestData"


def test_the_quantumleap_api_answers_the_state_as_of_an_instant(client, notify):
    """POST /v2/op/query?asOf=: each attribute at its last value at or
    before the instant (NGSIv2's time index), with its time."""
    for minute, (battery, mode) in enumerate([(90, "docked"), (80, "mowing"), (70, "mowing"), (60, "stuck")]):
        entity = {
            "id": "Robot:1",
            "type": "Robot",
            "battery": {"type": "Number", "value": battery},
            "TimeInstant": {"type": "DateTime", "value": at(minute)},
            **({"mode": {"type": "Text", "value": mode}} if minute % 2 == 0 else {}),
        }
        notify(client, {"subscriptionId": "s", "data": [entity]}, {"Fiware-Service": "acme"})
    body = {"entities": [{"idPattern": ".*", "type": "Robot"}]}
    headers = {"Fiware-Service": "acme"}
    [then] = client.post("/v2/op/query", params={"asOf": at(2.5)}, json=body, headers=headers).json()
    assert then["battery"]["value"] == 70 and then["mode"]["value"] == "mowing"
    assert then["battery"]["metadata"]["dateModified"]["value"].startswith("2024-05-01T10:02:00")
    assert then["mode"]["metadata"]["dateModified"]["value"].startswith("2024-05-01T10:02:00")
    [now] = client.post("/v2/op/query", json=body, headers=headers).json()
    assert now["battery"]["value"] == 60 and "metadata" not in now["battery"]
    assert client.post("/v2/op/query", params={"asOf": at(-1)}, json=body, headers=headers).json() == []
    bad = client.post("/v2/op/query", params={"asOf": "yesterday"}, json=body, headers=headers)
    assert bad.status_code == 400 and bad.json()["error"] == "BadRequest"
