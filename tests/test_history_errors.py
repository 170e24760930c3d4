"""Every client mistake is a 4xx in the NGSI error shape; nothing is a 500."""

from __future__ import annotations

import itertools
import random

import pytest

ENDPOINTS = [
    "/v2/entities",
    "/v2/entities/Room1",
    "/v2/entities/Room1/value",
    "/v2/entities/Room1/attrs/temperature",
    "/v2/entities/Room1/attrs/temperature/value",
    "/v2/types/Room",
    "/v2/types/Room/value",
    "/v2/types/Room/attrs/temperature",
    "/v2/types/Room/attrs/temperature/value",
    "/v2/attrs",
    "/v2/attrs/value",
    "/v2/attrs/temperature",
    "/v2/attrs/temperature/value",
]

BAD = {
    "fromDate": ["yesterday", "2024-02-30T00:00:00Z", "", '""', "2024-01-01T25:00:00Z", "99999-01-01", "1e10"],
    "toDate": ["later", "2024-01-01T00:00:00+25:00", "0000-01-01"],
    "lastN": ["0", "-1", "abc", "1.5", "1" * 40, " "],
    "limit": ["0", "-5", "x", "1" * 40],
    "offset": ["-1", "y", "1" * 40],
    "aggrMethod": ["median", "AVG ", "1"],
    "aggrPeriod": ["week", "HOURS"],
    "aggrScope": ["planet"],
    "idPattern": ["[", "(?P<", "*"],
    "attrs": ["a=b", "x(", "x(..)", "a;b"],
    "options": ["keyValues"],
    "georel": ["near;maxDistance:10"],
}

# Valid but unusual values: they must work (2xx) or be refused (4xx), never 500.
ODD = {
    "fromDate": [
        "9999-12-31T23:59:59.999999Z",
        "0001-01-01T00:00:00Z",
        "2024-05-01T10:00:00+14:00",
        "2024-05-01",
        '"2024-05-01T10:00:00"',
    ],
    "toDate": ["0001-01-01T00:00:00-12:00", "9999-12-31"],
    "lastN": ["1", "999999999999999999"],
    "limit": ["1", "999999999999999999"],
    "offset": ["0", "999999999999999999"],
    "aggrMethod": ["count", "Sum", "MAX"],
    "aggrPeriod": ["second", "YEAR"],
    "aggrScope": ["global", "entity"],
    "idPattern": [".*", "(a|b)*c", "^$", "é"],
    "id": [",", "Room1,Room1", "x" * 1000],
    "type": ["", ",", "Room,Lamp"],
    "attrs": [",,,", "temperature,temperature", "odom([0])", "t" * 256],
    "dropTable": ["true"],
}


@pytest.fixture(scope="module")
def loaded(client_factory, store_url_factory, notify):
    with client_factory(store_url_factory("errors")) as client:
        for i in range(3):
            notify(
                client,
                {
                    "data": [
                        {
                            "id": "Room1",
                            "type": "Room",
                            "TimeInstant": {"type": "DateTime", "value": f"2024-05-01T10:0{i}:00Z"},
                            "temperature": {"type": "Number", "value": 20 + i},
                            "name": {"type": "Text", "value": "k"},
                        }
                    ]
                },
            )
        yield client


def _assert_ngsi_error(response, status: int | None = None):
    assert 400 <= response.status_code < 500, (response.status_code, response.text)
    if status is not None:
        assert response.status_code == status, response.text
    body = response.json()
    assert set(body) == {"error", "description"}, body
    assert isinstance(body["error"], str) and body["error"]
    assert isinstance(body["description"], str) and body["description"]


# Parameters an endpoint does not take are ignored, as in QuantumLeap.
IGNORED = {
    "/v2/entities": {"aggrMethod", "aggrPeriod", "aggrScope", "attrs", "lastN", "options", "georel"},
}
for _e in ENDPOINTS:
    ignored = IGNORED.setdefault(_e, set())
    if _e.startswith("/v2/entities/"):
        ignored.add("idPattern")
    if "/attrs/" in _e:
        ignored.add("attrs")


@pytest.mark.parametrize(
    ("endpoint", "param"), [(e, p) for e, p in itertools.product(ENDPOINTS, BAD) if p not in IGNORED[e]]
)
def test_bad_parameters_are_400(loaded, endpoint, param):
    for value in BAD[param]:
        params = {param: value}
        if param in ("aggrPeriod", "aggrScope"):
            params["aggrMethod"] = "avg"
        response = loaded.get(endpoint, params=params)
        if param == "fromDate" and value == "":  # empty = not given: the same answer as without it
            without = loaded.get(endpoint, params={k: v for k, v in params.items() if k != param})
            assert (response.status_code, response.json()) == (without.status_code, without.json()), value
            assert response.status_code == 200, response.text
            continue
        _assert_ngsi_error(response, 400)


@pytest.mark.parametrize(("endpoint", "param"), list(itertools.product(ENDPOINTS, ODD)))
def test_odd_parameters_never_500(loaded, endpoint, param):
    for value in ODD[param]:
        response = loaded.get(endpoint, params={param: value})
        assert response.status_code < 500, (endpoint, param, value, response.text)
        if response.status_code >= 400:
            _assert_ngsi_error(response)


def test_combinations_never_500(loaded):
    values = {
        "lastN": [None, "2"],
        "limit": [None, "1"],
        "offset": [None, "1"],
        "aggrMethod": [None, "avg", "count"],
        "aggrPeriod": [None, "minute"],
        "aggrScope": [None, "global"],
        "fromDate": [None, "2024-05-01T10:01:00Z"],
        "attrs": [None, "temperature,name"],
    }
    keys = list(values)
    combos = list(itertools.product(*values.values()))
    rng = random.Random(3)  # a fixed sample of the 384 combinations per endpoint keeps this fast
    for endpoint in ENDPOINTS:
        for combo in rng.sample(combos, 40):
            params = {k: v for k, v in zip(keys, combo, strict=True) if v is not None}
            response = loaded.get(endpoint, params=params)
            assert response.status_code < 500, (endpoint, params, response.text)
            if response.status_code >= 400:
                _assert_ngsi_error(response)


def test_error_shape_for_each_status(loaded):
    _assert_ngsi_error(loaded.get("/v2/entities/Room1/attrs/temperature?lastN=0"), 400)
    _assert_ngsi_error(loaded.get("/v2/entities/Room1/attrs/name?aggrMethod=avg"), 404)
    _assert_ngsi_error(loaded.delete("/v2/entities/Nope"), 404)
    _assert_ngsi_error(loaded.get("/v2/nothing/here"), 404)
    _assert_ngsi_error(loaded.get("/v2/attrs", headers={"Fiware-Service": "bad tenant!"}), 400)
    _assert_ngsi_error(
        loaded.post("/v2/op/query", content=b"{not json", headers={"Content-Type": "application/json"}), 400
    )


def test_odd_path_segments(loaded):
    for path in [
        "/v2/entities/%00/attrs/x",
        "/v2/entities/a%2Fb",
        "/v2/types/%20",
        "/v2/attrs/%28%29",
        "/v2/entities/" + "x" * 2000,
        "/v2/entities/Room1/attrs/" + "y" * 300,
    ]:
        response = loaded.get(path)
        assert response.status_code < 500, (path, response.text)
        if response.status_code >= 400:
            _assert_ngsi_error(response)
