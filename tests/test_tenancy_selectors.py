"""One tenant rule everywhere: notify, queries, Grafana, the rejected store.

Before: a notification with both ``Fiware-Service`` and ``NGSILD-Tenant``
was stored under one (NGSILD-Tenant for NGSI-LD bodies) and queried under
the other (Fiware-Service first), and Grafana's ``?service=`` silently
overrode the header. Now conflicting selectors are a 400 on every endpoint,
the same tenant named twice is fine, and a notification refused for its
tenant is still kept.
"""

from __future__ import annotations

import orjson
import pytest

TIME = "2024-05-01T10:00:00Z"
V2 = {
    "subscriptionId": "s",
    "data": [
        {
            "id": "E1",
            "type": "T",
            "x": {"type": "Number", "value": 1},
            "TimeInstant": {"type": "DateTime", "value": TIME},
        }
    ],
}
LD = {
    "id": "urn:n",
    "type": "Notification",
    "data": [{"id": "E1", "type": "T", "x": {"type": "Property", "value": 1, "observedAt": TIME}}],
}
CONFLICT = {"Fiware-Service": "alpha", "NGSILD-Tenant": "beta"}


def _post(client, body, headers, url="/v2/notify"):
    return client.post(url, content=orjson.dumps(body), headers={"Content-Type": "application/json", **headers})


@pytest.mark.parametrize(
    ("body", "url"), [(V2, "/v2/notify"), (LD, "/v2/notify"), (LD, "/ngsi-ld/v1/notify"), (V2, "/ngsi-ld/v1/notify")]
)
def test_conflicting_notification_is_refused_and_kept(client, body, url):
    response = _post(client, body, CONFLICT, url)
    assert response.status_code == 400, response.text
    assert "conflicting tenant selectors" in response.json()["description"]
    for tenant in ("alpha", "beta"):
        assert client.get("/v2/entities", headers={"Fiware-Service": tenant}).json() == []
        # Neither tenant sees it: it claims both, so only the operator does.
        assert client.get("/v2/notify/rejected", headers={"Fiware-Service": tenant}).json() == []
    [kept] = client.get("/v2/notify/rejected", params={"allTenants": "true"}).json()
    assert kept["tenant"] == "alpha,beta"
    assert orjson.loads(kept["body"]) == body


def test_repeated_header_with_two_values_conflicts(client):
    headers = [("Content-Type", "application/json"), ("Fiware-Service", "alpha"), ("Fiware-Service", "beta")]
    response = client.post("/v2/notify", content=orjson.dumps(V2), headers=headers)
    assert response.status_code == 400, response.text
    response = client.get("/v2/entities", headers=headers)
    assert response.status_code == 400, response.text


@pytest.mark.parametrize(
    "headers",
    [
        {"Fiware-Service": "Alpha", "NGSILD-Tenant": "alpha"},
        {"NGSILD-Tenant": "alpha"},
        {"Fiware-Service": " alpha "},
        {"Fiware-Service": "alpha", "NGSILD-Tenant": ""},
    ],
)
@pytest.mark.parametrize("body", [V2, LD])
def test_one_tenant_however_named_is_stored_and_read_back_the_same(client, headers, body):
    assert _post(client, body, headers).status_code == 200
    for read_headers in (headers, {"Fiware-Service": "alpha"}, {"NGSILD-Tenant": "ALPHA"}):
        [entity] = client.get("/v2/entities", headers=read_headers).json()
        assert entity["id"] == "E1"
    assert client.get("/v2/entities").json() == []  # not in the default tenant


QUERIES = [
    ("get", "/v2/entities"),
    ("get", "/v2/entities/E1"),
    ("get", "/v2/types/T"),
    ("get", "/v2/attrs"),
    ("get", "/v2/attrs/x"),
    ("get", "/v2/notify/rejected"),
    ("get", "/v2/notify/subscriptions"),
    ("delete", "/v2/entities/E1"),
    ("delete", "/v2/types/T"),
    ("post", "/v2/op/query"),
    ("put", "/v2/notify/subscriptions/s1"),
]


@pytest.fixture(scope="module")
def refusing(client_factory, store_url_factory):
    """One store per backend for the refusals below: nothing reaches it."""
    with client_factory(store_url_factory("refusing")) as client:
        yield client


@pytest.mark.parametrize(("method", "url"), QUERIES)
def test_every_endpoint_refuses_conflicting_selectors(refusing, method, url):
    client = refusing
    body = {"entities": [{"id": "E1"}]} if url == "/v2/op/query" else {"attrs": ["id", "x"]}
    kwargs = {"json": body} if method in ("post", "put") else {}
    response = client.request(method.upper(), url, headers=CONFLICT, **kwargs)
    assert response.status_code == 400, response.text
    assert response.json()["error"] == "BadRequest"
    assert "conflicting tenant selectors" in response.json()["description"]


GRAFANA = [
    ("get", "/grafana/infinity/entities"),
    ("get", "/grafana/infinity/latest?attrs=x"),
    ("get", "/grafana/simplejson/"),
    ("post", "/grafana/simplejson/search"),
    ("post", "/grafana/simplejson/query"),
    ("post", "/grafana/simplejson/tag-keys"),
]


@pytest.fixture(scope="module")
def two_tenants(client_factory, store_url_factory):
    with client_factory(store_url_factory("tenants")) as client:
        for tenant in ("alpha", "beta"):
            assert _post(client, V2, {"Fiware-Service": tenant}).status_code == 200
        yield client


@pytest.mark.parametrize(("method", "url"), GRAFANA)
def test_grafana_service_parameter_must_agree_with_the_header(two_tenants, method, url):
    sep = "&" if "?" in url else "?"
    kwargs = {"json": {}} if method == "post" else {}
    conflicting = two_tenants.request(
        method.upper(), f"{url}{sep}service=beta", headers={"Fiware-Service": "alpha"}, **kwargs
    )
    assert conflicting.status_code == 400, conflicting.text
    assert "conflicting tenant selectors" in conflicting.json()["description"]
    for headers, query in (
        ({"Fiware-Service": "alpha"}, "service=ALPHA"),
        ({}, "service=alpha"),
        ({"NGSILD-Tenant": "alpha"}, ""),
    ):
        response = two_tenants.request(method.upper(), f"{url}{sep}{query}", headers=headers, **kwargs)
        assert response.status_code == 200, (headers, query, response.text)


def test_grafana_reads_the_tenant_it_is_told(two_tenants):
    alpha = two_tenants.get("/grafana/infinity/entities?service=alpha").json()
    assert [row["entity"] for row in alpha] == ["E1"]
    assert two_tenants.get("/grafana/infinity/entities", headers={"NGSILD-Tenant": "gamma"}).json() == []
