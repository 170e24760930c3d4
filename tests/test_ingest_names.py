"""One attribute-name rule for ingest and queries (tsdb_service.parse.names).

A name the ingest accepts can be asked for by that name on every endpoint;
a name it could not be asked for is refused with a 400 that says why, and
the notification is kept in the rejected store.
"""

from __future__ import annotations

from urllib.parse import quote

import orjson
import pytest

from tsdb_service.core.errors import BadRequest
from tsdb_service.history.valuepath import parse_value_path
from tsdb_service.parse.names import name_problem

GOOD = [
    "temperature",
    "Ünïcødé_温度_🌡",
    "https://example.org/ns#speed",
    "ex:speed",
    "a.b$c",
    "x" * 256,
    "temperature~ground",
    "a&b?c%d",
    "@id-ish",
    "urn:ngsi-ld:Property:1",
    "a/b",
]
BAD = [
    "",
    "x" * 257,
    "a b",
    " a",
    "a ",
    "a\t",
    "a\nb",
    "a\x00",
    "a\x7f",
    "a\x9f",
    "a\u3000b",
    "a\u00a0",
    ".",
    "..",
    *(f"a{c}b" for c in "<>\"'=;(),"),
]

# Every name works as one URL path segment too, "/" percent-encoded as %2F
# (the history routes are matched on the raw path: tsdb_service.http.rawpath).
ADDRESSABLE_IN_PATH = GOOD


@pytest.mark.parametrize("name", GOOD)
def test_good_names(name):
    assert name_problem(name) is None
    assert parse_value_path(name).attr == name


@pytest.mark.parametrize("name", BAD)
def test_bad_names_are_refused_on_both_sides(name):
    assert name_problem(name) is not None
    with pytest.raises(BadRequest):
        parse_value_path(name)


@pytest.mark.parametrize("name", ['quo"te', "Temp'; DROP TABLE x;--", " padded ", "x" * 300, "a,b", "f(x)"])
def test_ingest_refuses_with_the_reason_and_keeps_the_body(client, name):
    headers = {"Fiware-Service": "names"}
    body = {
        "subscriptionId": "s",
        "data": [
            {"id": "E", "type": "T", name: {"type": "Number", "value": 1}, "fine": {"type": "Number", "value": 2}}
        ],
    }
    response = client.post("/v2/notify", json=body, headers=headers)
    assert response.status_code == 400, response.text
    description = response.json()["description"]
    assert "data[0]: attribute name" in description and "without white space" in description
    [kept] = client.get("/v2/notify/rejected", headers=headers).json()
    assert orjson.loads(kept["body"]) == body and kept["error"] == "ParseError"
    assert client.get("/v2/entities", headers=headers).json() == []  # nothing of it was stored


def test_values_layout_refuses_bad_names(client):
    response = client.put("/v2/notify/subscriptions/s1", json={"attrs": ["id", "te mp"]})
    assert response.status_code == 400
    assert "'te mp'" in response.json()["description"]


@pytest.fixture(scope="module")
def named(client_factory, store_url_factory):
    with client_factory(store_url_factory("names")) as client:
        entity = {"id": "E1", "type": "T"}
        entity.update({name: {"type": "Number", "value": i} for i, name in enumerate(GOOD)})
        entity["TimeInstant"] = {"type": "DateTime", "value": "2024-05-01T10:00:00Z"}
        response = client.post("/v2/notify", json={"subscriptionId": "s", "data": [entity]})
        assert response.status_code == 200, response.text
        yield client


@pytest.mark.parametrize("name", ADDRESSABLE_IN_PATH)
def test_every_path_endpoint_answers_by_the_stored_name(named, name):
    value = GOOD.index(name)
    segment = quote(name, safe="")
    for url in (f"/v2/entities/E1/attrs/{segment}", f"/v2/types/T/attrs/{segment}", f"/v2/attrs/{segment}"):
        response = named.get(url)
        assert response.status_code == 200, (url, response.text)
        assert str(value) in response.text, (url, response.text)
    assert named.get(f"/v2/entities/E1/attrs/{segment}/value").json()["values"] == [value]


@pytest.mark.parametrize("name", GOOD)
def test_every_list_endpoint_answers_by_the_stored_name(named, name):
    value = GOOD.index(name)
    entity = named.get("/v2/entities/E1", params={"attrs": name}).json()
    assert entity["attributes"] == [{"attrName": name, "values": [value]}]
    [found] = named.post("/v2/op/query", json={"entities": [{"id": "E1"}], "attrs": [name]}).json()
    assert found[name]["value"] == value
    rows = named.get("/grafana/infinity/latest", params={"id": "E1", "attrs": name}).json()
    assert [row[name] for row in rows] == [value]


def test_entity_lists_every_name(named):
    entity = named.get("/v2/entities/E1").json()
    assert {a["attrName"] for a in entity["attributes"]} == {*GOOD, "TimeInstant"}
