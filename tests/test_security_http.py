"""End to end over real HTTP (uvicorn in its own process, as deployed): an
Orion-style notification carrying its key in a custom header, reads with a
JWT checked against a JWKS from a real local issuer, CORS preflights, and a
refused notification that leaves the connection usable."""

from __future__ import annotations

import httpx
import pytest

from tests.support.jwks_server import ISSUER, Issuer
from tests.support.server import ServerProcess

ORION_KEY = "orion-subscription-key-0123456789"
ADMIN_KEY = "operator-admin-key-0123456789"
ORIGIN = "https://grafana.example.org"
NOTE = {
    "subscriptionId": "s1",
    "data": [{"id": "urn:Robot:1", "type": "Robot", "battery": {"type": "Number", "value": 42}}],
}
ACME = {"Fiware-Service": "acme", "Fiware-ServicePath": "/"}


@pytest.fixture(scope="module")
def issuer():
    with Issuer() as running:
        yield running


def _env(issuer: Issuer) -> dict[str, str]:
    return {
        "TSDB_API_KEYS": f"{ORION_KEY}:write:acme;{ADMIN_KEY}:admin",
        "TSDB_API_KEY_HEADER": "X-Orion-Key",
        "TSDB_JWT_JWKS_URL": issuer.jwks_url,
        "TSDB_JWT_AUDIENCE": "tsdb-service",
        "TSDB_JWT_ISSUER": ISSUER,
        "TSDB_JWT_TENANTS_CLAIM": "tenants",
        "TSDB_CORS_ORIGINS": ORIGIN,
    }


@pytest.fixture
def server(store_url, issuer, tmp_path):
    """On both backends: what the notification stored is read back."""
    with ServerProcess(store_url, extra_env=_env(issuer), log_dir=tmp_path) as running:
        yield running


@pytest.fixture
def embedded_server(issuer, tmp_path):
    with ServerProcess(tmp_path / "tsdb.duckdb", extra_env=_env(issuer)) as running:
        yield running


def test_orion_key_header_notification_then_jwt_read(server, issuer):
    with httpx.Client(base_url=server.url, timeout=10) as http:
        refused = http.post("/v2/notify", json=NOTE, headers=ACME)
        assert refused.status_code == 401
        assert refused.headers["www-authenticate"].startswith("Bearer")
        # the same connection stays usable after an answer sent before the body was read
        stored = http.post("/v2/notify", json=NOTE, headers={**ACME, "X-Orion-Key": ORION_KEY})
        assert stored.status_code == 200, stored.text
        other = http.post("/v2/notify", json=NOTE, headers={"Fiware-Service": "other", "X-Orion-Key": ORION_KEY})
        assert other.status_code == 403

        token = issuer.token(aud="tsdb-service", realm_access={"roles": ["read"]}, tenants=["acme"])
        read = http.get("/v2/entities/urn:Robot:1/attrs/battery", headers={**ACME, "Authorization": f"Bearer {token}"})
        assert read.status_code == 200, read.text
        assert read.json()["values"] == [42]
        assert http.get("/v2/entities", headers={**ACME, "X-Orion-Key": ORION_KEY}).status_code == 403
        assert http.get("/health").json() == {"status": "pass"}


def test_cors_preflight_and_admin_over_http(embedded_server):
    with httpx.Client(base_url=embedded_server.url, timeout=10) as http:
        preflight = http.options(
            "/v2/notify",
            headers={
                "Origin": ORIGIN,
                "Access-Control-Request-Method": "POST",
                "Access-Control-Request-Headers": "authorization, content-type",
            },
        )
        assert preflight.status_code == 200
        assert preflight.headers["access-control-allow-origin"] == ORIGIN
        refused = http.get("/v2/notify/rejected", headers={"Origin": ORIGIN})
        assert refused.status_code == 401
        assert refused.headers["access-control-allow-origin"] == ORIGIN  # the browser may read why
        bad = http.post(
            "/v2/notify",
            content=b"{broken",
            headers={**ACME, "Content-Type": "application/json", "X-Orion-Key": ORION_KEY},
        )
        assert bad.status_code == 400
        kept = http.get("/v2/notify/rejected", headers={**ACME, "Authorization": f"Bearer {ADMIN_KEY}"})
        assert kept.status_code == 200
        assert ORION_KEY not in kept.text and len(kept.json()) == 1
