"""The request-context precedence table (``parse.request_context``), on every API.

One rule for the tenant on notify, the /v2 history routes, ``/v2/op/query``,
Grafana and the NGSI-LD temporal reads: every non-blank selector must name
the same tenant (a conflict is a 400: NGSI shape on /v2 and Grafana,
ProblemDetails ``BadRequestData`` on NGSI-LD), a blank one is absent, none is
the default tenant. Service paths: a non-blank Grafana ``servicepath``
replaces the header, a blank one is absent. One ``MAX_IDS`` for id lists.
"""

from __future__ import annotations

import orjson
import pytest

from tsdb_service.parse.request_context import MAX_IDS

TIME = "2024-05-01T10:00:00Z"
BODY = {
    "subscriptionId": "s",
    "data": [
        {
            "id": "urn:ngsi-ld:T:E1",
            "type": "T",
            "x": {"type": "Number", "value": 1},
            "TimeInstant": {"type": "DateTime", "value": TIME},
        }
    ],
}
E1 = "urn:ngsi-ld:T:E1"
LD_PROBLEM = "https://uri.etsi.org/ngsi-ld/errors/BadRequestData"


@pytest.fixture(scope="module")
def stored(client_factory, store_url_factory):
    """E1 in tenant ``alpha`` under ``/a``, and in the default tenant under ``/b``."""
    with client_factory(store_url_factory("precedence")) as client:
        for headers in ({"Fiware-Service": "alpha", "Fiware-ServicePath": "/a"}, {"Fiware-ServicePath": "/b"}):
            response = client.post(
                "/v2/notify", content=orjson.dumps(BODY), headers={"Content-Type": "application/json", **headers}
            )
            assert response.status_code == 200, response.text
        yield client


# --- one read per API, answering the entity ids it sees --------------------------------


def _history(client, headers, query=""):
    response = client.get(f"/v2/entities{query}", headers=headers)
    return response, (lambda: [e["id"] for e in response.json()])


def _op_query(client, headers, query=""):
    response = client.post("/v2/op/query", json={"entities": [{"idPattern": ".*"}]}, headers=headers)
    return response, (lambda: [e["id"] for e in response.json()])


def _grafana(client, headers, query=""):
    response = client.get(f"/grafana/infinity/entities{query}", headers=headers)
    return response, (lambda: [row["entity"] for row in response.json()])


def _ld(client, headers, query=""):
    response = client.get("/ngsi-ld/v1/temporal/entities?type=T", headers={"Accept": "application/json", **headers})
    return response, (lambda: [e["id"] for e in response.json()])


READS = {"history": _history, "op/query": _op_query, "grafana": _grafana, "ngsi-ld": _ld}

# (headers, the tenant they select: "alpha" or "" for the default)
SAME_TENANT = [
    ({"Fiware-Service": "alpha"}, "alpha"),
    ({"NGSILD-Tenant": "ALPHA"}, "alpha"),
    ({"Fiware-Service": "Alpha", "NGSILD-Tenant": "alpha"}, "alpha"),
    ({"Fiware-Service": "", "NGSILD-Tenant": "alpha"}, "alpha"),  # blank = absent
    ({"Fiware-Service": " alpha "}, "alpha"),
    ({}, ""),
    ({"Fiware-Service": ""}, ""),
]


@pytest.mark.parametrize("api", READS)
@pytest.mark.parametrize(("headers", "tenant"), SAME_TENANT)
def test_selectors_naming_one_tenant_read_it(stored, api, headers, tenant):
    response, ids = READS[api](stored, headers)
    assert response.status_code == 200, response.text
    assert ids() == [E1]
    other = {"Fiware-Service": "gamma"}
    response, ids = READS[api](stored, other)
    if api == "ngsi-ld":
        assert response.status_code == 404  # NonexistentTenant
    else:
        assert response.status_code == 200 and ids() == []


def _assert_conflict(api, response):
    assert response.status_code == 400, response.text
    body = response.json()
    if api == "ngsi-ld":
        assert body["type"] == LD_PROBLEM
        assert "conflicting tenant selectors" in body["detail"]
    else:
        assert body["error"] == "BadRequest"
        assert "conflicting tenant selectors" in body["description"]


@pytest.mark.parametrize("api", READS)
def test_two_tenants_are_a_400_on_every_read(stored, api):
    response, _ = READS[api](stored, {"Fiware-Service": "alpha", "NGSILD-Tenant": "beta"})
    _assert_conflict(api, response)


@pytest.mark.parametrize("api", READS)
def test_an_invalid_tenant_is_a_400_on_every_read(stored, api):
    response, _ = READS[api](stored, {"NGSILD-Tenant": "no-dashes"})
    assert response.status_code == 400, response.text
    if api == "ngsi-ld":
        assert response.json()["type"] == LD_PROBLEM
    else:
        assert "invalid tenant" in response.json()["description"]


@pytest.mark.parametrize("url", ["/v2/notify", "/ngsi-ld/v1/notify"])
def test_notify_follows_the_same_rule(client, url):
    def post(headers):
        return client.post(url, content=orjson.dumps(BODY), headers={"Content-Type": "application/json", **headers})

    conflict = post({"Fiware-Service": "alpha", "NGSILD-Tenant": "beta"})
    assert conflict.status_code == 400 and "conflicting tenant selectors" in conflict.json()["description"]
    assert post({"Fiware-Service": "", "NGSILD-Tenant": "Alpha"}).status_code == 200
    [entity] = client.get("/v2/entities", headers={"Fiware-Service": "alpha"}).json()
    assert entity["id"] == E1
    assert client.get("/v2/entities").json() == []


# --- Grafana's parameters ----------------------------------------------------------------


@pytest.mark.parametrize(
    ("headers", "query", "expected"),
    [
        ({"Fiware-Service": "alpha"}, "?service=beta", 400),  # header vs parameter
        ({}, "?service=alpha&service=beta", 400),  # parameter twice
        ({"Fiware-Service": "alpha"}, "?service=ALPHA", [E1]),
        ({"Fiware-Service": "alpha"}, "?service=", [E1]),  # blank parameter = absent
        ({}, "?service=", [E1]),  # the default tenant, as everywhere
        ({}, "?service=%20", [E1]),
        ({}, "?service=alpha", [E1]),
        ({}, "?service=gamma", []),
    ],
)
def test_grafana_service_parameter(stored, headers, query, expected):
    response, ids = _grafana(stored, headers, query)
    if expected == 400:
        _assert_conflict("grafana", response)
    else:
        assert response.status_code == 200, response.text
        assert ids() == expected


@pytest.mark.parametrize(
    ("header", "query", "expected"),
    [
        ("/a", "", [E1]),
        ("/a", "&servicepath=/b", []),  # a non-blank parameter replaces the header
        ("/b", "&servicepath=/a", [E1]),
        ("/b", "&servicepath=", []),  # a blank one is absent: the header's /b
        (None, "&servicepath=", [E1]),  # neither: the whole tenant
        ("/b", "&servicepath=/", [E1]),  # the parameter's whole tenant
    ],
)
def test_grafana_service_path_parameter(stored, header, query, expected):
    headers = {} if header is None else {"Fiware-ServicePath": header}
    response, ids = _grafana(stored, headers, f"?service=alpha{query}")
    assert response.status_code == 200, response.text
    assert ids() == expected


# --- one MAX_IDS -------------------------------------------------------------------------


@pytest.mark.parametrize("api", ["history", "grafana"])
def test_id_lists_share_one_maximum(stored, api):
    path = "/v2/entities" if api == "history" else "/grafana/infinity/entities"
    headers = {"Fiware-Service": "alpha"}
    ids = [E1] + [_short(i) for i in range(MAX_IDS - 1)]  # short: a client's URL has a limit too
    response = stored.get(path, params={"id": ",".join(ids)}, headers=headers)
    assert response.status_code == 200, response.text
    response = stored.get(path, params={"id": ",".join([*ids, "one-more"])}, headers=headers)
    assert response.status_code == 400, response.text
    assert f"at most {MAX_IDS}" in response.json()["description"]


def _short(i: int) -> str:
    """``i`` in base 36: 10,000 ids fit in httpx's 64 KiB query."""
    digits = "0123456789abcdefghijklmnopqrstuvwxyz"
    out = ""
    while True:
        i, r = divmod(i, 36)
        out = digits[r] + out
        if not i:
            return out


def test_op_query_entities_share_the_maximum(stored):
    entities = [{"id": f"urn:ngsi-ld:T:other{i}"} for i in range(MAX_IDS + 1)]
    response = stored.post("/v2/op/query", json={"entities": entities}, headers={"Fiware-Service": "alpha"})
    assert response.status_code == 400, response.text
    assert f"at most {MAX_IDS}" in response.json()["description"]
