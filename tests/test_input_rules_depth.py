"""One nesting limit for values: what the ingest accepts, every read renders.

The response encoder stops at 254 levels; a value nested deeper was accepted
with 200 and then turned every read that included it into a 500. The ingest
now refuses values (and metadata) nested deeper than ``MAX_DEPTH`` with 400,
keeps the notification in the rejected store, and everything it accepted is
readable on every read path: history, value paths, op/query and Grafana.
"""

from __future__ import annotations

import orjson
import pytest

from tsdb_service.core.errors import ParseError
from tsdb_service.parse.values import MAX_DEPTH, to_json

HEADERS = {"Fiware-Service": "deep"}
TIME = "2024-05-01T10:00:00Z"


def nested(levels: int) -> object:
    """``levels`` containers around a number: objects and arrays alternating,
    so value paths can reach the bottom."""
    value: object = 1
    for i in range(levels):
        value = {"k": value} if i % 2 else [value]
    return value


def nested_text(levels: int) -> bytes:
    """``nested(levels)`` as JSON text, for depths no encoder writes."""
    head = "".join('{"k":' if i % 2 else "[" for i in reversed(range(levels)))
    tail = "".join("}" if i % 2 else "]" for i in range(levels))
    return (head + "1" + tail).encode()


def notification(value: object, *, entity_id: str = "E1", metadata: dict | None = None) -> dict:
    attr = {"type": "StructuredValue", "value": value}
    if metadata is not None:
        attr["metadata"] = metadata
    entity = {"id": entity_id, "type": "T", "deep": attr, "TimeInstant": {"type": "DateTime", "value": TIME}}
    return {"subscriptionId": "s", "data": [entity]}


def test_to_json_enforces_the_limit():
    assert orjson.loads(nested_text(7)) == nested(7)
    assert orjson.loads(to_json(nested(MAX_DEPTH))) == nested(MAX_DEPTH)
    with pytest.raises(ParseError, match=f"nested more than {MAX_DEPTH} levels"):
        to_json(nested(MAX_DEPTH + 1))
    with pytest.raises(ParseError):
        to_json(nested(300))  # beyond what the encoder itself can write


def test_brackets_in_strings_do_not_count():
    value = {"text": "[" * 500, "list": [[["{" * 300]]]}
    assert orjson.loads(to_json(value)) == value


@pytest.mark.parametrize("levels", [MAX_DEPTH + 1, 300, 1000])
def test_too_deep_is_refused_and_kept(client, levels):
    body = orjson.dumps(notification("HERE")).replace(b'"HERE"', nested_text(levels))
    response = client.post("/v2/notify", content=body, headers={**HEADERS, "Content-Type": "application/json"})
    assert response.status_code == 400, response.text
    assert f"data[0]: value or metadata nested more than {MAX_DEPTH} levels" in response.json()["description"]
    [kept] = client.get("/v2/notify/rejected", headers=HEADERS).json()
    assert kept["body"].encode() == body
    assert client.get("/v2/entities", headers=HEADERS).json() == []


def test_too_deep_metadata_is_refused(client):
    body = notification(5, metadata={"m": {"type": "StructuredValue", "value": nested(MAX_DEPTH)}})
    response = client.post("/v2/notify", json=body, headers=HEADERS)
    assert response.status_code == 400, response.text


def test_too_deep_ngsi_ld_sub_property_is_refused(client):
    entity = {
        "id": "urn:E1",
        "type": "T",
        "p": {"type": "Property", "value": 1, "sub": {"type": "Property", "value": nested(MAX_DEPTH)}},
    }
    body = {"id": "urn:n", "type": "Notification", "data": [entity]}
    response = client.post("/ngsi-ld/v1/notify", json=body, headers=HEADERS)
    assert response.status_code == 400, response.text


@pytest.fixture(scope="module")
def deepest(client_factory, store_url_factory):
    """A store holding a value exactly at the limit, in a tenant of its own."""
    with client_factory(store_url_factory("deep")) as client:
        response = client.post("/v2/notify", json=notification(nested(MAX_DEPTH)), headers=HEADERS)
        assert response.status_code == 200, response.text
        yield client


def _path_to_bottom(levels: int, stop: int) -> str:
    """A value path ``stop`` steps into ``nested(levels)`` (at most 32 steps)."""
    steps = []
    for i in reversed(range(levels - stop, levels)):
        steps.append(".k" if i % 2 else "[0]")
    return "deep(" + "".join(steps).lstrip(".") + ")"


@pytest.mark.parametrize(
    "url",
    [
        "/v2/entities/E1",
        "/v2/entities/E1/value",
        "/v2/entities/E1/attrs/deep",
        "/v2/entities/E1/attrs/deep/value",
        "/v2/types/T",
        "/v2/types/T/value",
        "/v2/types/T/attrs/deep",
        "/v2/types/T/attrs/deep/value",
        "/v2/attrs",
        "/v2/attrs/value",
        "/v2/attrs/deep",
        "/v2/attrs/deep/value",
        "/v2/entities/E1?lastN=1",
        "/v2/attrs?aggrMethod=count",
        "/v2/types/T?aggrMethod=count&aggrScope=global",
    ],
)
def test_every_history_read_renders_it(deepest, url):
    response = deepest.get(url, headers=HEADERS)
    assert response.status_code == 200, (url, response.text[:300])
    if "aggrMethod" not in url:
        assert orjson.dumps(nested(MAX_DEPTH)) in response.content


def test_value_paths_reach_inside_it(deepest):
    path = _path_to_bottom(MAX_DEPTH, 32)
    response = deepest.get("/v2/entities/E1", params={"attrs": path}, headers=HEADERS)
    assert response.status_code == 200, response.text[:300]
    assert orjson.dumps(nested(MAX_DEPTH - 32)) in response.content


def test_op_query_renders_it(deepest):
    response = deepest.post("/v2/op/query", json={"entities": [{"id": "E1"}]}, headers=HEADERS)
    assert response.status_code == 200, response.text[:300]
    assert response.json()[0]["deep"]["value"] == nested(MAX_DEPTH)


@pytest.mark.parametrize("endpoint", ["series", "latest", "states", "events", "aggregate", "entities", "positions"])
def test_grafana_infinity_renders_it(deepest, endpoint):
    params = {"attrs": "deep", "service": "deep"}
    if endpoint == "positions":
        params["location"] = "deep"
    if endpoint == "aggregate":
        params["method"] = "count"  # averages of a structured value are refused by design
    response = deepest.get(f"/grafana/infinity/{endpoint}", params=params)
    assert response.status_code == 200, (endpoint, response.text[:300])


@pytest.mark.parametrize("fmt", ["timeseries", "table", "dataframe"])
def test_grafana_simplejson_renders_it(deepest, fmt):
    body = {
        "targets": [{"target": "E1/deep", "refId": "A", "payload": {"format": fmt}}],
        "range": {"from": "2024-05-01T00:00:00Z", "to": "2024-05-02T00:00:00Z"},
    }
    response = deepest.post("/grafana/simplejson/query", json=body, headers=HEADERS)
    assert response.status_code == 200, response.text[:300]
