"""What the ETSI NGSI-LD conformance suite's temporal cases found (issue 28),
one test per kind of failure, on both backends (the suite itself runs on
DuckDB in ``test_ngsild_etsi_suite``):

* instants come back as sent (no fractional part when there was none);
* status codes and error types: 400 BadRequestData for ids and names no
  endpoint could hold, 404 for what is not there, InvalidRequest for a
  parameter outside its grammar;
* LanguageProperty, JsonProperty and VocabProperty in every representation,
  ``lang`` and the concise representation;
* query answers hold only the entities asked for (deleted ones, other
  types, attributes and datasets not asked for stay out), in id order;
* a client's instanceId is kept; aggregation answers per entity;
* names mean what the write's @context says (020_01_01: read without that
  context, a name is its IRI).
"""

from __future__ import annotations

import json

import pytest

from tsdb_service.core.model import INSTANCE_URN_PREFIX

BASE = "/ngsi-ld/v1/temporal/entities"
QUERY = "/ngsi-ld/v1/temporal/entityOperations/query"
JSON = {"Content-Type": "application/json"}
ERRORS = "https://uri.etsi.org/ngsi-ld/errors/"
CTX_URL = "https://contexts.example/vehicle.jsonld"
VOCAB = "https://example.org/vehicle#"
LINK = {"Link": f'<{CTX_URL}>; rel="http://www.w3.org/ns/json-ld#context"; type="application/ld+json"'}
A, B, BUS = "urn:ngsi-ld:Vehicle:A", "urn:ngsi-ld:Vehicle:B", "urn:ngsi-ld:Bus:C"


def vehicle(eid: str, etype: str = "Vehicle", day: str = "2020-08-01", **extra) -> dict:
    return {
        "id": eid,
        "type": etype,
        "speed": [
            {"type": "Property", "value": 120, "observedAt": f"{day}T12:03:00Z"},
            {"type": "Property", "value": 80, "observedAt": f"{day}T12:05:00.250Z"},
            {"type": "Property", "value": 100, "observedAt": f"{day}T12:07:00.000123Z"},
        ],
        "fuelLevel": [{"type": "Property", "value": 67, "observedAt": f"{day}T12:03:00Z"}],
        **extra,
    }


def create(client, body: dict, headers: dict | None = None) -> None:
    response = client.post(BASE, json=body, headers={**JSON, **(headers or {})})
    assert response.status_code == 201, response.text


def problem(response, status: int, ld_type: str) -> None:
    assert response.status_code == status, response.text
    assert response.json()["type"] == ERRORS + ld_type, response.text


@pytest.fixture
def fleet(client):
    create(client, vehicle(A))
    create(client, vehicle(B, day="2020-09-01"))
    create(client, vehicle(BUS, etype="Bus"))
    return client


# --- time format ---------------------------------------------------------------------


def test_instants_come_back_as_sent(fleet):
    speed = fleet.get(f"{BASE}/{A}").json()["speed"]
    assert [i["observedAt"] for i in speed] == [
        "2020-08-01T12:03:00Z",
        "2020-08-01T12:05:00.250Z",
        "2020-08-01T12:07:00.000123Z",
    ]
    values = fleet.get(f"{BASE}/{A}", params={"options": "temporalValues", "attrs": "speed"}).json()
    assert [t for _, t in values["speed"]["values"]] == [i["observedAt"] for i in speed]
    hourly = fleet.get(
        f"{BASE}/{A}",
        params={"format": "aggregatedValues", "aggrMethods": "max", "aggrPeriodDuration": "PT1H", "attrs": "speed"},
    ).json()
    assert hourly["speed"]["max"] == [[120, "2020-08-01T12:03:00Z", "2020-08-01T13:03:00Z"]]


def test_the_quantumleap_api_keeps_its_time_format(fleet):
    history = fleet.get(f"/v2/entities/{A}/attrs/speed", params={"type": "Vehicle"}).json()
    assert history["index"] == [
        "2020-08-01T12:03:00.000+00:00",
        "2020-08-01T12:05:00.250+00:00",
        "2020-08-01T12:07:00.000+00:00",
    ]


# --- status codes and error types ----------------------------------------------------


@pytest.mark.parametrize(
    ("method", "path"),
    [
        ("GET", f"{BASE}/invalidUri"),
        ("DELETE", f"{BASE}/invalidId"),
        ("POST", f"{BASE}//attrs"),
        ("POST", f"{BASE}/notAnId/attrs"),
        ("DELETE", f"{BASE}//attrs/speed"),
        ("DELETE", f"{BASE}/{A}/attrs/invalid(Name"),
        ("DELETE", f"{BASE}/{A}/attrs/%252e%252e"),
        ("DELETE", f"{BASE}/{A}/attrs/%2e"),
        ("DELETE", f"{BASE}/{A}/attrs//{INSTANCE_URN_PREFIX}1"),
        ("DELETE", f"{BASE}/{A}/attrs/speed/invalidId"),
        ("PATCH", f"{BASE}//attrs/speed/{INSTANCE_URN_PREFIX}1"),
        ("PATCH", f"{BASE}/{A}/attrs/invalid(Id/{INSTANCE_URN_PREFIX}1"),
    ],
)
def test_ids_and_names_no_endpoint_could_hold_are_bad_request_data(fleet, method, path):
    body = {"speed": {"type": "Property", "value": 1}} if method in ("POST", "PATCH") else None
    response = fleet.request(method, path, json=body, headers=JSON if body else {})
    problem(response, 400, "BadRequestData")


def test_ngsiv2_ids_that_are_no_uris_still_name_their_entities(client, notify):
    """An id that is no URI is a 400 only when no entity has it: NGSIv2
    data keeps its ids (``Room1``) in this API too."""
    room = {"id": "Room1", "type": "Room", "temperature": {"type": "Number", "value": 21.5, "metadata": {}}}
    notify(client, {"subscriptionId": "s", "data": [room]})
    assert client.get(f"{BASE}/Room1").json()["temperature"][0]["value"] == 21.5
    problem(client.get(f"{BASE}/Room2"), 400, "BadRequestData")
    assert client.delete(f"{BASE}/Room1").status_code == 204
    problem(client.get(f"{BASE}/Room1"), 404, "ResourceNotFound")  # it was one: deleted


def test_what_is_not_there_is_404(fleet):
    problem(fleet.get(f"{BASE}/urn:ngsi-ld:Vehicle:nobody"), 404, "ResourceNotFound")
    problem(fleet.get(f"{BASE}/{A}", params={"attrs": "unknownAttribute"}), 404, "ResourceNotFound")
    problem(fleet.get(f"{BASE}/{A}", params={"pick": "unknown"}), 404, "ResourceNotFound")
    problem(fleet.get(f"{BASE}/{A}", params={"omit": "id,type,speed,fuelLevel"}), 404, "ResourceNotFound")
    problem(fleet.get(f"{BASE}/{A}", params={"q": "speed>1000"}), 404, "ResourceNotFound")  # was a 500
    assert fleet.get(f"{BASE}/{A}", params={"q": "speed>100"}).status_code == 200
    assert fleet.delete(f"{BASE}/{A}").status_code == 204
    problem(fleet.get(f"{BASE}/{A}"), 404, "ResourceNotFound")  # deleted: no instance left
    problem(fleet.delete(f"{BASE}/{B}/attrs/speed/urn:ngsi-ld:Instance:unknown"), 404, "ResourceNotFound")
    # An empty instanceId segment is no route for PATCH (405), as the suite's 016_02_04 wants.
    assert fleet.patch(f"{BASE}/{B}/attrs/speed/", json={}, headers=JSON).status_code in (404, 405)


@pytest.mark.parametrize(
    "params",
    [
        {"pick": "speed", "omit": "speed"},
        {"pick": "speed", "attrs": "fuelLevel"},
        {"omit": "speed", "attrs": "fuelLevel"},
        {"timerel": "after", "timeAt": "2020-08-01"},
        {"orderBy": "name"},
        {"orderBy": "id,name"},
        {"lang": "not a tag"},
    ],
)
def test_invalid_combinations_are_bad_request_data(fleet, params):
    problem(fleet.get(BASE, params={"type": "Vehicle", **params}), 400, "BadRequestData")
    problem(fleet.get(f"{BASE}/{A}", params=params), 400, "BadRequestData")


@pytest.mark.parametrize(
    "params", [{"format": "invalidFormat"}, {"options": "invalidOptions"}, {"options": "temporalValues,x"}]
)
def test_parameters_outside_their_grammar_are_invalid_requests(fleet, params):
    problem(fleet.get(BASE, params={"type": "Vehicle", **params}), 400, "InvalidRequest")


def test_format_wins_and_unused_aggregation_parameters_are_ignored(fleet):
    params = {"type": "Vehicle", "options": "aggregatedValues", "format": "temporalValues", "aggrMethods": "sum"}
    answer = fleet.get(BASE, params=params)
    assert answer.status_code == 200, answer.text
    assert "values" in answer.json()[0]["speed"]


# --- property kinds ------------------------------------------------------------------


STREET = {
    "id": "urn:ngsi-ld:Vehicle:street",
    "type": "Vehicle",
    "street": [
        {
            "type": "LanguageProperty",
            "languageMap": {"fr": "Grand Place", "nl": "Grote Markt"},
            "observedAt": "2020-08-01T12:03:00Z",
        },
        {"languageMap": {"@none": "Main", "es": "Gran Mercado"}, "observedAt": "2020-08-01T12:05:00Z"},
    ],
    "settings": [
        {"type": "JsonProperty", "json": {"value": 120, "unit": ["km", "h"]}, "observedAt": "2020-08-01T12:03:00Z"}
    ],
    "category": [{"type": "VocabProperty", "vocab": "monument", "observedAt": "2020-08-01T12:03:00Z"}],
}


def test_language_json_and_vocab_properties_in_every_representation(client):
    create(client, STREET)
    path = f"{BASE}/{STREET['id']}"
    normalized = client.get(path).json()
    assert [(i["type"], i["languageMap"]) for i in normalized["street"]] == [
        ("LanguageProperty", {"fr": "Grand Place", "nl": "Grote Markt"}),
        ("LanguageProperty", {"@none": "Main", "es": "Gran Mercado"}),
    ]
    assert normalized["settings"][0]["json"] == {"value": 120, "unit": ["km", "h"]}
    assert normalized["category"][0]["vocab"] == "monument"
    simple = client.get(path, params={"options": "temporalValues"}).json()
    assert simple["street"] == {
        "type": "LanguageProperty",
        "languageMaps": [
            [{"languageMap": {"fr": "Grand Place", "nl": "Grote Markt"}}, "2020-08-01T12:03:00Z"],
            [{"languageMap": {"@none": "Main", "es": "Gran Mercado"}}, "2020-08-01T12:05:00Z"],
        ],
    }
    assert simple["settings"]["jsons"] == [[{"json": {"value": 120, "unit": ["km", "h"]}}, "2020-08-01T12:03:00Z"]]
    assert simple["category"]["vocabs"] == [[{"vocab": "monument"}, "2020-08-01T12:03:00Z"]]


def test_lang_picks_one_language_per_instance(client):
    create(client, STREET)
    path = f"{BASE}/{STREET['id']}"
    picked = client.get(path, params={"lang": "nl,es;q=0.5", "attrs": "street"}).json()["street"]
    assert [(i["type"], i["value"], i["lang"]) for i in picked] == [
        ("Property", "Grote Markt", "nl"),
        ("Property", "Gran Mercado", "es"),
    ]
    fallback = client.get(path, params={"lang": "de", "attrs": "street"}).json()["street"]
    assert [(i["value"], i["lang"]) for i in fallback] == [("Grand Place", "fr"), ("Main", "@none")]
    simple = client.get(path, params={"lang": "*", "attrs": "street", "format": "temporalValues"}).json()["street"]
    assert simple == {
        "type": "Property",
        "values": [["Grand Place", "2020-08-01T12:03:00Z"], ["Main", "2020-08-01T12:05:00Z"]],
    }


def test_the_concise_representation_leaves_out_the_types_values_say(client):
    create(
        client,
        {
            **STREET,
            "speed": [
                {
                    "type": "Property",
                    "value": 3,
                    "observedAt": "2020-08-01T12:03:00Z",
                    "accuracy": {"type": "Property", "value": 0.5},
                }
            ],
        },
    )
    got = client.get(f"{BASE}/{STREET['id']}", params={"format": "concise"}).json()
    assert "type" not in got["street"][0] and got["street"][0]["languageMap"]
    assert got["speed"][0]["value"] == 3 and "type" not in got["speed"][0]
    assert got["speed"][0]["accuracy"] == {"value": 0.5}
    assert got == client.get(f"{BASE}/{STREET['id']}", params={"options": "concise"}).json()

    # Written back, the concise answer is the same entity (our instanceIds aside: new instances get new ones).
    def without_ids(entity: dict) -> dict:
        return {
            k: [{m: v for m, v in i.items() if m != "instanceId"} for i in v] if isinstance(v, list) else v
            for k, v in entity.items()
            if k != "id"
        }

    create(client, {**without_ids(got), "id": "urn:ngsi-ld:Vehicle:again"})
    again = client.get(f"{BASE}/urn:ngsi-ld:Vehicle:again", params={"format": "concise"}).json()
    assert without_ids(again) == without_ids(got)


# --- which entities, in which order --------------------------------------------------


def ids(response) -> list[str]:
    assert response.status_code == 200, response.text
    return [e["id"] for e in response.json()]


def test_answers_hold_only_the_entities_asked_for(fleet):
    everything = {"timerel": "after", "timeAt": "2020-01-01T00:00:00Z"}
    assert ids(fleet.get(BASE, params={"type": "Vehicle", **everything})) == [A, B]
    assert ids(fleet.get(BASE, params={"type": "Bus", **everything})) == [BUS]
    # Only entities with an instance in the window of what is asked.
    assert ids(fleet.get(BASE, params={"type": "Vehicle", "timerel": "before", "timeAt": "2020-09-01T00:00:00Z"})) == [
        A
    ]
    # Deleted entities are gone from answers, and from counts.
    assert fleet.delete(f"{BASE}/{A}").status_code == 204
    counted = fleet.get(BASE, params={"type": "Vehicle,Bus", "count": "true", **everything})
    assert ids(counted) == [BUS, B] and counted.headers["NGSILD-Results-Count"] == "2"
    assert ids(fleet.get(BASE, params={"type": "Vehicle", "limit": "1", **everything})) == [B]
    # Past one page: the entities are asked about first (all of them to count).
    first = fleet.get(BASE, params={"type": "Vehicle,Bus", "limit": "1", **everything})
    assert ids(first) == [BUS] and 'rel="next"' in first.headers["Link"]
    last = fleet.get(BASE, params={"type": "Vehicle,Bus", "limit": "1", "offset": "1", "count": "true", **everything})
    assert ids(last) == [B] and last.headers["NGSILD-Results-Count"] == "2" and 'rel="next"' not in last.headers["Link"]
    # An attribute deleted everywhere takes its entities out of attrs queries.
    assert fleet.delete(f"{BASE}/{BUS}/attrs/fuelLevel").status_code == 204
    assert ids(fleet.get(BASE, params={"attrs": "fuelLevel", **everything})) == [B]


def test_entity_order_both_ways(fleet):
    everything = {"timerel": "after", "timeAt": "2020-01-01T00:00:00Z", "type": "Vehicle,Bus"}
    assert ids(fleet.get(BASE, params={**everything, "orderBy": "id"})) == [BUS, A, B]
    assert ids(fleet.get(BASE, params={**everything, "orderBy": "id;desc"})) == [B, A, BUS]
    paged = fleet.get(BASE, params={**everything, "orderBy": "id;desc", "limit": "1", "offset": "1"})
    assert ids(paged) == [A]


def test_dataset_ids_select_instances_and_entities(client):
    create(
        client,
        {
            "id": A,
            "type": "Vehicle",
            "speed": [
                {"type": "Property", "value": 1, "observedAt": "2020-08-01T12:00:00Z"},
                {"type": "Property", "value": 2, "observedAt": "2020-08-01T12:00:00Z", "datasetId": "urn:ds:gps"},
            ],
        },
    )
    create(
        client,
        {"id": B, "type": "Vehicle", "speed": [{"type": "Property", "value": 3, "observedAt": "2020-08-01T12:00:00Z"}]},
    )
    gps = client.get(BASE, params={"type": "Vehicle", "datasetId": "urn:ds:gps"})
    assert ids(gps) == [A] and [i["value"] for i in gps.json()[0]["speed"]] == [2]
    default = client.get(BASE, params={"type": "Vehicle", "datasetId": "@none"})
    assert ids(default) == [A, B] and [i["value"] for i in default.json()[0]["speed"]] == [1]


def test_query_bodies_select_like_query_strings(fleet):
    body = {
        "type": "Query",
        "entities": [{"type": "Vehicle"}],
        "attrs": ["speed"],
        "temporalQ": {"timerel": "after", "timeAt": "2020-08-01T12:04:00Z"},
    }
    answer = fleet.post(QUERY, json=body, headers=JSON)
    assert ids(answer) == [A, B]
    assert set(answer.json()[0]) == {"id", "type", "speed"}
    aggregated = fleet.post(
        QUERY, json={**body, "temporalQ": {**body["temporalQ"], "aggrMethods": ["max"]}}, headers=JSON
    )
    assert [e["speed"]["max"][0][0] for e in aggregated.json()] == [100, 120]
    bad = {**body, "temporalQ": {**body["temporalQ"], "aggrMethods": "max", "aggrPeriodDuration": "bogus"}}
    problem(fleet.post(QUERY, json=bad, headers=JSON), 400, "BadRequestData")


# --- instances -----------------------------------------------------------------------


def test_a_clients_instance_id_is_kept(client):
    mine = "urn:ngsi-ld:Instance:5bd19b87-a1a0-4f7f-8589-be5a09d16107"
    create(
        client,
        {
            "id": A,
            "type": "Vehicle",
            "speed": [
                {"type": "Property", "value": 120, "observedAt": "2020-08-01T12:03:00Z", "instanceId": mine},
                {"type": "Property", "value": 80, "observedAt": "2020-08-01T12:05:00Z"},
            ],
        },
    )
    speed = client.get(f"{BASE}/{A}").json()["speed"]
    assert speed[0]["instanceId"] == mine and speed[1]["instanceId"].startswith(INSTANCE_URN_PREFIX)
    patched = client.patch(f"{BASE}/{A}/attrs/speed/{mine}", json={"value": 121}, headers=JSON)
    assert patched.status_code == 204, patched.text
    speed = client.get(f"{BASE}/{A}").json()["speed"]
    assert (speed[0]["value"], speed[0]["instanceId"]) == (121, mine)
    assert client.delete(f"{BASE}/{A}/attrs/speed/{mine}").status_code == 204
    assert [i["value"] for i in client.get(f"{BASE}/{A}").json()["speed"]] == [80]
    twice = vehicle(B)
    twice["speed"][0]["instanceId"] = twice["speed"][1]["instanceId"] = mine
    problem(client.post(BASE, json=twice, headers=JSON), 400, "BadRequestData")
    problem(
        client.post(BASE, json={**vehicle(B), "speed": {"value": 1, "instanceId": "no uri"}}, headers=JSON),
        400,
        "BadRequestData",
    )


def test_aggregation_answers_for_each_entity(fleet):
    params = {"type": "Vehicle", "format": "aggregatedValues", "aggrMethods": "sum,totalCount", "attrs": "speed"}
    answer = fleet.get(BASE, params={**params, "timerel": "before", "timeAt": "2020-09-01T12:06:00Z"}).json()
    assert [(e["id"], e["speed"]["sum"][0][0], e["speed"]["totalCount"][0][0]) for e in answer] == [
        (A, 300, 3),
        (B, 200, 2),
    ]


# --- names and @contexts --------------------------------------------------------------


@pytest.fixture
def with_context(client_factory, store_url, tmp_path):
    path = tmp_path / "vehicle.jsonld"
    path.write_text(json.dumps({"@context": {"speed": VOCAB + "speed", "Vehicle": VOCAB + "Vehicle"}}))
    with client_factory(store_url, ngsild_contexts=f"{CTX_URL}={path}") as c:
        yield c


def test_names_mean_what_the_writes_context_says(with_context):
    client = with_context
    create(client, {**vehicle(A), "@context": [CTX_URL]}, headers={"Content-Type": "application/ld+json"})
    plain = client.get(f"{BASE}/{A}").json()  # 020_01_01: no context, the IRIs
    assert plain["type"] == VOCAB + "Vehicle" and VOCAB + "speed" in plain and "fuelLevel" in plain
    linked = client.get(f"{BASE}/{A}", headers=LINK).json()
    assert linked["type"] == "Vehicle" and "speed" in linked
    assert ids(client.get(BASE, params={"type": "Vehicle", "attrs": "speed"}, headers=LINK)) == [A]
    assert client.get(BASE, params={"type": "Vehicle"}).json() == []  # core Vehicle is another type
    # A URL's attribute name is read with the request's Link context.
    problem(client.delete(f"{BASE}/{A}/attrs/speed"), 404, "ResourceNotFound")
    assert client.delete(f"{BASE}/{A}/attrs/speed", headers=LINK).status_code == 204
    # The NGSIv2 API shows what is stored: the IRI where the context is not the core one.
    attrs = {
        a["attrName"] for a in client.get(f"/v2/entities/{A}", params={"type": VOCAB + "Vehicle"}).json()["attributes"]
    }
    assert attrs == {"fuelLevel"}


# --- scope and scopeQ ----------------------------------------------------------------


def test_scope_is_stored_and_scope_q_selects_by_the_scope_of_the_time(client):
    """Clauses 4.18, 4.19: scopeQ selects entities by the scopes they had in
    the window (a replaced scope still selects the history it held for)."""
    create(client, {**vehicle(A), "scope": "/Madrid/Gardens/ParqueNorte"})
    create(client, {**vehicle(B), "scope": ["/Madrid/Centro", "/Company/Fleet"]})
    create(client, vehicle(BUS, etype="Bus"))
    scope = client.get(f"{BASE}/{A}", params={"attrs": "scope"}).json()["scope"]
    assert [(i["type"], i["value"]) for i in scope] == [("Property", "/Madrid/Gardens/ParqueNorte")]
    everything = {"type": "Vehicle,Bus", "timerel": "after", "timeAt": "2020-01-01T00:00:00Z"}
    cases = {
        "/Madrid/#": [A, B],
        "/Madrid": [],
        "/Madrid/+": [B],
        "/+/Gardens/#": [A],
        "/Madrid/#;/Company/#": [B],
        "/Company/Fleet,/Madrid/Gardens/ParqueNorte": [A, B],
        "(/Nowhere,/Company/#);/Madrid/Centro": [B],
        "/#": [A, B],
    }
    for query, expected in cases.items():
        assert ids(client.get(BASE, params={**everything, "scopeQ": query})) == expected, query
    body = {"type": "Query", "entities": [{"type": "Vehicle"}], "scopeQ": "/Company/#"}
    assert ids(client.post(QUERY, json=body, headers=JSON)) == [B]
    # A scope replaced now leaves the history before it to the old one.
    assert client.post(f"{BASE}/{B}/attrs", json={"scope": "/Elsewhere"}, headers=JSON).status_code == 204
    assert ids(client.get(BASE, params={**everything, "scopeQ": "/Company/#"})) == [B]
    [now] = client.get(BASE, params={**everything, "scopeQ": "/Elsewhere"}).json()
    assert set(now) == {"id", "type", "scope"}  # nothing of B's was observed under /Elsewhere but the scope itself
    for bad in ("Madrid", "/Madrid/#/x", "/a;;/b", "(/a", "/a/#)"):
        problem(client.get(BASE, params={**everything, "scopeQ": bad}), 400, "BadRequestData")
    for bad_scope in ("Madrid", ["/ok", "/no#"], [], 5):
        problem(
            client.post(BASE, json={**vehicle("urn:ngsi-ld:Vehicle:s"), "scope": bad_scope}, headers=JSON),
            400,
            "BadRequestData",
        )
