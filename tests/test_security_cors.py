"""CORS: a browser client (Grafana's browser-side plugins, a notebook) may
call us from the origins an operator allows, and from no other. Before this,
every preflight answered 405, and 405s said nothing about what is allowed."""

from __future__ import annotations

import pytest

ORIGIN = "https://grafana.example.org"
PREFLIGHT = {
    "Origin": ORIGIN,
    "Access-Control-Request-Method": "POST",
    "Access-Control-Request-Headers": "content-type, fiware-service, authorization",
}


@pytest.fixture
def embedded_db(tmp_path) -> str:
    """The guard and CORS answer before any storage is touched, so these
    tests need one backend only: an embedded DuckDB file."""
    return str(tmp_path / "tsdb.duckdb")


@pytest.mark.parametrize("path", ["/v2/notify", "/v2/entities", "/grafana/simplejson/query", "/ngsi-ld/v1/notify"])
def test_preflight_is_answered_for_an_allowed_origin(client_factory, embedded_db, path):
    with client_factory(embedded_db, cors_origins=f"{ORIGIN}, https://other.example") as client:
        response = client.options(path, headers=PREFLIGHT)
    assert response.status_code == 200, response.text
    assert response.headers["access-control-allow-origin"] == ORIGIN
    assert "POST" in response.headers["access-control-allow-methods"]
    allowed = response.headers["access-control-allow-headers"].lower()
    assert "fiware-service" in allowed and "authorization" in allowed


def test_actual_requests_carry_the_origin_on_both_paths(client_factory, embedded_db):
    body = {"data": [{"id": "r1", "type": "Robot", "v": {"type": "Number", "value": 1}}]}
    with client_factory(embedded_db, cors_origins=ORIGIN) as client:
        stored = client.post("/v2/notify", json=body, headers={"Origin": ORIGIN})
        read = client.get("/v2/entities", headers={"Origin": ORIGIN})
    assert stored.status_code == 200 and read.status_code == 200
    assert stored.headers["access-control-allow-origin"] == ORIGIN
    assert read.headers["access-control-allow-origin"] == ORIGIN


def test_other_origins_get_no_grant(client_factory, embedded_db):
    with client_factory(embedded_db, cors_origins=ORIGIN) as client:
        preflight = client.options("/v2/entities", headers={**PREFLIGHT, "Origin": "https://evil.example"})
        read = client.get("/v2/entities", headers={"Origin": "https://evil.example"})
    assert preflight.status_code == 400
    assert "access-control-allow-origin" not in preflight.headers
    assert read.status_code == 200 and "access-control-allow-origin" not in read.headers


def test_off_by_default_no_origin_is_granted(client_factory, embedded_db):
    with client_factory(embedded_db) as client:
        _assert_no_grant(client)


def _assert_no_grant(client) -> None:
    response = client.get("/v2/entities", headers={"Origin": ORIGIN})
    assert "access-control-allow-origin" not in response.headers
    preflight = client.options("/v2/entities", headers=PREFLIGHT)
    assert "access-control-allow-origin" not in preflight.headers
    assert preflight.status_code == 405 and preflight.headers["allow"]


@pytest.mark.parametrize(
    ("method", "path", "allowed"),
    [
        ("OPTIONS", "/v2/entities/e1", {"GET", "DELETE"}),
        ("PUT", "/v2/types/T", {"GET", "DELETE"}),
        ("GET", "/v2/notify", {"POST"}),
        ("DELETE", "/v2/attrs", {"GET"}),
        ("POST", "/version", {"GET"}),
        ("GET", "/v2/notify/subscriptions/s1", {"PUT"}),
    ],
)
def test_405_names_every_allowed_method(client_factory, embedded_db, method, path, allowed):
    with client_factory(embedded_db) as client:
        response = client.request(method, path)
    assert response.status_code == 405, response.text
    assert {m.strip() for m in response.headers["allow"].split(",")} == allowed
    assert response.json()["error"] == "MethodNotAllowed"


def test_wildcard_origin(client_factory, embedded_db):
    with client_factory(embedded_db, cors_origins="*", cors_allow_unauthenticated=True) as client:
        response = client.options("/v2/entities", headers={**PREFLIGHT, "Origin": "https://any.example"})
    assert response.status_code == 200
    assert response.headers["access-control-allow-origin"] == "*"
