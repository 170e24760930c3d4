"""Every integer parameter is range-checked: out of range is a 400, never a 500.

``GET /v2/notify/rejected?offset=9223372036854775808`` used to reach the
database, which cannot hold the number, and answer 500. Every integer a
client can send (history, rejected store, Grafana parameters and bodies)
is now checked against one range before it reaches the store.
"""

from __future__ import annotations

import pytest

from tsdb_service.parse.request_context import MAX_INT_PARAM

HEADERS = {"Fiware-Service": "ints"}
TOO_BIG = ["9223372036854775808", "99999999999999999999", str(MAX_INT_PARAM + 1), "1" + "0" * 40]
NEGATIVE = ["-1", "-9223372036854775809"]
NOT_INTEGERS = ["1.5", "abc", "0x10", "1e3", " "]


@pytest.fixture(scope="module")
def loaded(client_factory, store_url_factory):
    with client_factory(store_url_factory("ints")) as client:
        body = {
            "subscriptionId": "s",
            "data": [
                {
                    "id": "E1",
                    "type": "T",
                    "x": {"type": "Number", "value": 1},
                    "TimeInstant": {"type": "DateTime", "value": "2024-05-01T10:00:00Z"},
                }
            ],
        }
        assert client.post("/v2/notify", json=body, headers=HEADERS).status_code == 200
        assert (
            client.post(
                "/v2/notify", content=b"{broken", headers={**HEADERS, "Content-Type": "application/json"}
            ).status_code
            == 400
        )
        yield client


HISTORY = [
    "/v2/entities/E1",
    "/v2/entities/E1/value",
    "/v2/entities/E1/attrs/x",
    "/v2/entities/E1/attrs/x/value",
    "/v2/types/T",
    "/v2/types/T/attrs/x",
    "/v2/attrs",
    "/v2/attrs/x",
    "/v2/attrs/x/value",
]
CASES = (
    [(url, name) for url in HISTORY for name in ("limit", "offset", "lastN")]
    + [("/v2/entities", "limit"), ("/v2/entities", "offset")]
    + [("/v2/notify/rejected", "limit"), ("/v2/notify/rejected", "offset")]
)


def _assert_400(response, name):
    assert response.status_code == 400, response.text
    body = response.json()
    assert body["error"] == "BadRequest" and name in body["description"], body


@pytest.mark.parametrize(("url", "name"), CASES)
def test_out_of_range_is_400(loaded, url, name):
    for value in TOO_BIG + NEGATIVE + NOT_INTEGERS:
        _assert_400(loaded.get(url, params={name: value}, headers=HEADERS), name)


@pytest.mark.parametrize(("url", "name"), [case for case in CASES if case != ("/v2/notify/rejected", "limit")])
def test_the_largest_allowed_value_is_answered(loaded, url, name):
    response = loaded.get(url, params={name: str(MAX_INT_PARAM)}, headers=HEADERS)
    assert response.status_code == 200, response.text


def test_rejected_offset_from_the_issue(loaded):
    _assert_400(loaded.get("/v2/notify/rejected", params={"offset": "9223372036854775808"}, headers=HEADERS), "offset")
    paged = loaded.get("/v2/notify/rejected", params={"offset": "0", "limit": "1"}, headers=HEADERS)
    assert paged.status_code == 200 and len(paged.json()) == 1


INFINITY = [
    ("series", "max_points"),
    ("series", "interval_ms"),
    ("states", "max_points"),
    ("events", "limit"),
    ("positions", "max_points"),
    ("aggregate", "limit"),
]


@pytest.mark.parametrize(("endpoint", "name"), INFINITY)
def test_grafana_infinity_integers(loaded, endpoint, name):
    url = f"/grafana/infinity/{endpoint}"
    params = {"attrs": "x", "service": "ints"}
    for value in [*TOO_BIG, "1e400", "nan", "inf", *NEGATIVE, "0", "abc"]:
        _assert_400(loaded.get(url, params={**params, name: value}), name)
    for value in ("1", "1500.0", str(MAX_INT_PARAM)):
        response = loaded.get(url, params={**params, name: value})
        assert response.status_code == 200, (value, response.text)


@pytest.mark.parametrize("name", ["maxDataPoints", "intervalMs"])
def test_grafana_simplejson_body_integers(loaded, name):
    target = {"targets": [{"target": "E1/x", "refId": "A"}]}
    for value in [2**63, 10**40, 1e300, -1, 0, "abc"]:
        response = loaded.post("/grafana/simplejson/query", json={**target, name: value}, headers=HEADERS)
        _assert_400(response, name)
    response = loaded.post("/grafana/simplejson/query", json={**target, name: 500}, headers=HEADERS)
    assert response.status_code == 200, response.text


@pytest.mark.parametrize("bound", [2**63, -(2**63) - 1, 10**40, 1e300, -1e300])
def test_grafana_time_bounds_out_of_range(loaded, bound):
    body = {"targets": [{"target": "E1/x", "refId": "A"}], "range": {"from": bound, "to": bound}}
    response = loaded.post("/grafana/simplejson/query", json=body, headers=HEADERS)
    assert response.status_code == 400, response.text
    response = loaded.get("/grafana/infinity/series", params={"attrs": "x", "service": "ints", "from": str(bound)})
    assert response.status_code == 400, response.text
