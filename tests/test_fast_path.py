"""The history reads served ahead of the framework (``http.fastpath``) answer
exactly as the framework does: the same bodies, statuses, error shapes,
read budgets, headers and request-metric labels."""

from __future__ import annotations

import pytest

HEADERS = {"Fiware-Service": "fast", "Fiware-ServicePath": "/"}
REQUESTS = [
    "/v2/entities/Robot:1/attrs/speed?lastN=3",
    "/v2/entities/Robot:1/attrs/speed/value?lastN=2&offset=1",
    "/v2/entities/Robot:1?attrs=speed,mode",
    "/v2/entities/Robot:1/value",
    "/v2/entities/Robot:1/attrs/speed?aggrMethod=avg&aggrPeriod=minute",
    "/v2/types/Robot/attrs/speed?lastN=1",
    "/v2/types/Robot?limit=2",
    "/v2/attrs/speed?lastN=2",
    "/v2/attrs?lastN=1",
    "/v2/entities/Robot:1/attrs/speed?lastN=x",  # 400, NGSI shape
    "/v2/entities/Nobody/attrs/speed",  # nothing matched
    "/v2/entities/Robot:1/attrs/speed?georel=near;maxDistance:10&geometry=point&coords=0,0",
    "/v2/entities/Robot:1/attrs/speed?options=sql",  # NotSupported
]


@pytest.fixture
def loaded(client, notify):
    for i in range(6):
        body = {
            "subscriptionId": "s",
            "data": [
                {
                    "id": f"Robot:{1 + i % 2}",
                    "type": "Robot",
                    "speed": {"type": "Number", "value": i * 1.5},
                    "mode": {"type": "Text", "value": ["idle", "busy"][i % 2]},
                    "location": {"type": "geo:point", "value": f"0.0{i}, 0.0{i}"},
                    "TimeInstant": {"type": "DateTime", "value": f"2024-05-01T10:0{i}:00Z"},
                }
            ],
        }
        notify(client, body, HEADERS)
    return client


def _answers(client) -> list[tuple]:
    out = []
    for path in REQUESTS:
        r = client.get(path, headers=HEADERS)
        out.append((path, r.status_code, r.headers.get("content-type"), r.content))
    return out


def test_the_fast_path_answers_as_the_framework(loaded):
    fast = loaded.app.fast
    assert fast.match({"type": "http", "method": "GET", "path": "/v2/attrs/speed", "root_path": ""}) is not None
    with_fast = _answers(loaded)
    kept, fast._routes = fast._routes, []  # every request through the framework
    try:
        assert _answers(loaded) == with_fast
    finally:
        fast._routes = kept
    assert {status for _, status, _, _ in with_fast} >= {200, 400}


def test_a_read_budget_holds_on_the_fast_path(client_factory, store_url, notify):
    with client_factory(store_url, read_max_rows=2) as client:
        for i in range(5):
            body = {"data": [{"id": "R", "type": "T", "v": {"type": "Number", "value": i}}]}
            notify(client, body, HEADERS)
        r = client.get("/v2/entities/R/attrs/v", headers=HEADERS)
        assert r.status_code == 422 and r.json()["error"] == "QueryTooLarge", r.text


def test_the_request_metric_names_the_route_template(loaded):
    loaded.get("/v2/entities/Robot:1/attrs/speed?lastN=1", headers=HEADERS)
    text = loaded.get("/metrics").text
    assert 'route="/v2/entities/{entity_id}/attrs/{attr_name}"' in text


def test_other_methods_still_go_through_the_framework(loaded):
    for method in ("HEAD", "PUT"):
        r = loaded.request(method, "/v2/entities/Robot:1/attrs/speed", headers=HEADERS)
        assert r.status_code == 405 and "GET" in r.headers["allow"]
