"""OAuth2 bearer tokens (JWT) verified against a JWKS that a real local HTTP
server publishes, as Keycloak does, or against a configured key or secret
(Keyrock signs with the application's JWT secret). Scopes and tenants come
from configurable claims."""

from __future__ import annotations

import base64
import hashlib
import hmac
import json
import time

import jwt
import pytest
from cryptography.hazmat.primitives import serialization

from tests.support.jwks_server import ISSUER, Issuer

AUD = "tsdb-service"
KEYCLOAK = {"jwt_audience": AUD, "jwt_issuer": ISSUER, "jwt_tenants_claim": "tenants"}
NOTE = {"data": [{"id": "r1", "type": "Robot", "battery": {"type": "Number", "value": 80}}]}


@pytest.fixture
def embedded_db(tmp_path) -> str:
    """The guard and CORS answer before any storage is touched, so these
    tests need one backend only: an embedded DuckDB file."""
    return str(tmp_path / "tsdb.duckdb")


def bearer(token: str, **extra) -> dict:
    return {"Authorization": f"Bearer {token}", **extra}


@pytest.fixture
def issuer():
    with Issuer() as running:
        yield running


@pytest.fixture
def keycloak(client_factory, embedded_db, issuer):
    with client_factory(embedded_db, jwt_jwks_url=issuer.jwks_url, **KEYCLOAK) as client:
        yield client


def realm_token(issuer: Issuer, roles: list[str], tenants=("acme",), **claims) -> str:
    return issuer.token(aud=AUD, realm_access={"roles": roles}, tenants=list(tenants), **claims)


def test_keycloak_roles_grant_scopes_and_tenants(keycloak, issuer):
    writer = realm_token(issuer, ["write", "offline_access"])
    reader = realm_token(issuer, ["read"], tenants=["ACME"])
    acme = {"Fiware-Service": "acme"}
    assert keycloak.post("/v2/notify", json=NOTE, headers=bearer(writer, **acme)).status_code == 200
    assert keycloak.get("/v2/entities", headers=bearer(writer, **acme)).status_code == 403
    assert keycloak.get("/v2/entities", headers=bearer(reader, **acme)).json()[0]["id"] == "r1"
    assert keycloak.get("/v2/entities", headers=bearer(reader, **{"Fiware-Service": "other"})).status_code == 403
    assert keycloak.delete("/v2/entities/r1", headers=bearer(reader, **acme)).status_code == 403
    admin = realm_token(issuer, ["admin"])
    assert keycloak.delete("/v2/entities/r1", headers=bearer(admin, **acme)).status_code == 204
    assert issuer.fetches == 1  # fetched once, then cached


def test_oauth2_scope_claim(keycloak, issuer):
    token = issuer.token(aud=AUD, scope="openid read profile", tenants=["acme"])
    assert keycloak.get("/v2/entities", headers=bearer(token, **{"Fiware-Service": "acme"})).status_code == 200


@pytest.mark.parametrize(
    ("claims", "why"),
    [
        ({"aud": "someone-else"}, "audience"),
        ({"iss": "http://evil.test"}, "issuer"),
        ({"exp": int(time.time()) - 3600}, "expired"),
    ],
)
def test_invalid_tokens_are_401(keycloak, issuer, claims, why):
    token = issuer.token(**{"aud": AUD, "realm_access": {"roles": ["admin"]}, **claims})
    response = keycloak.get("/v2/entities", headers=bearer(token))
    assert response.status_code == 401
    assert 'error="invalid_token"' in response.headers["www-authenticate"]
    assert why in response.json()["description"].lower()


def test_a_token_without_expiry_is_refused(keycloak, issuer):
    key = issuer.keys[issuer.kid]
    claims = {"iss": ISSUER, "aud": AUD, "scope": "read"}
    token = jwt.encode(claims, key, algorithm="RS256", headers={"kid": issuer.kid})
    assert keycloak.get("/v2/entities", headers=bearer(token)).status_code == 401


def test_forged_signature_and_alg_none_are_refused(keycloak, issuer):
    good = realm_token(issuer, ["admin"])
    header, payload, signature = good.split(".")
    tampered = jwt.encode(
        {"iss": ISSUER, "aud": AUD, "exp": int(time.time()) + 60, "scope": "admin"}, key=None, algorithm="none"
    )
    for token in (f"{header}.{payload}.{signature[:-4]}AAAA", tampered):
        assert keycloak.get("/v2/entities", headers=bearer(token)).status_code == 401


def test_public_key_as_hmac_secret_is_refused(keycloak, issuer):
    """The classic algorithm confusion: sign HS256 with the published key."""
    public_pem = (
        issuer.keys[issuer.kid]
        .public_key()
        .public_bytes(serialization.Encoding.PEM, serialization.PublicFormat.SubjectPublicKeyInfo)
    )
    payload = {"iss": ISSUER, "aud": AUD, "exp": int(time.time()) + 60, "scope": "admin"}

    def b64(raw: bytes) -> str:
        return base64.urlsafe_b64encode(raw).rstrip(b"=").decode()

    signing = f"{b64(json.dumps({'alg': 'HS256', 'kid': issuer.kid}).encode())}.{b64(json.dumps(payload).encode())}"
    token = f"{signing}.{b64(hmac.new(public_pem, signing.encode(), hashlib.sha256).digest())}"
    assert keycloak.get("/v2/entities", headers=bearer(token)).status_code == 401


def test_rotated_key_is_fetched_unknown_keys_are_not_hammered(client_factory, embedded_db, issuer):
    with client_factory(embedded_db, jwt_jwks_url=issuer.jwks_url, jwt_jwks_cache_seconds=1, **KEYCLOAK) as client:
        first = realm_token(issuer, ["read"], tenants=["-"])
        assert client.get("/v2/entities", headers=bearer(first)).status_code == 200
        issuer.rotate(publish=False)
        rogue = realm_token(issuer, ["read"], tenants=["-"])
        for _ in range(5):
            assert client.get("/v2/entities", headers=bearer(rogue)).status_code == 401
        assert issuer.fetches <= 2
        issuer.published.append(issuer.kid)  # the issuer publishes its new key
        time.sleep(1.1)
        assert client.get("/v2/entities", headers=bearer(rogue)).status_code == 200


def test_issuer_unreachable_is_503_then_recovers(client_factory, embedded_db, issuer):
    issuer.available = False
    with client_factory(embedded_db, jwt_jwks_url=issuer.jwks_url, jwt_jwks_cache_seconds=1, **KEYCLOAK) as client:
        token = realm_token(issuer, ["read"], tenants=["-"])
        response = client.get("/v2/entities", headers=bearer(token))
        assert response.status_code == 503 and response.json()["error"] == "ServiceUnavailable"
        issuer.available = True
        time.sleep(1.1)
        assert client.get("/v2/entities", headers=bearer(token)).status_code == 200


def test_keyrock_hs256_secret_and_role_objects(client_factory, embedded_db):
    secret = "keyrock-application-jwt-secret-0123456789"
    token = jwt.encode(
        {
            "app_id": AUD,
            "aud": AUD,
            "exp": int(time.time()) + 60,
            "roles": [{"id": "r-1", "name": "tsdb:write"}, {"id": "r-2", "name": "read"}],
        },
        secret,
        algorithm="HS256",
    )
    with client_factory(embedded_db, jwt_key=secret, jwt_audience=AUD, jwt_scope_prefix="tsdb:") as client:
        assert client.post("/v2/notify", json=NOTE, headers=bearer(token)).status_code == 200
        assert client.get("/v2/entities", headers=bearer(token)).status_code == 403  # "read" lacks the prefix
        forged = jwt.encode(
            {"aud": AUD, "exp": int(time.time()) + 60, "roles": [{"name": "tsdb:admin"}]},
            "not-the-secret-0123456789-abcdefghij",
            algorithm="HS256",
        )
        assert client.get("/v2/entities", headers=bearer(forged)).status_code == 401


def test_static_public_key(client_factory, embedded_db, issuer):
    pem = (
        issuer.keys[issuer.kid]
        .public_key()
        .public_bytes(serialization.Encoding.PEM, serialization.PublicFormat.SubjectPublicKeyInfo)
        .decode()
    )
    with client_factory(embedded_db, jwt_key=pem, jwt_audience=AUD) as client:
        token = issuer.token(aud=AUD, scope="read")
        assert client.get("/v2/entities", headers=bearer(token)).status_code == 200
        assert issuer.fetches == 0


def test_keys_and_tokens_together(client_factory, embedded_db, issuer):
    key = "orion-notifications-0123456789"
    with client_factory(embedded_db, api_keys=f"{key}:write", jwt_jwks_url=issuer.jwks_url, jwt_audience=AUD) as client:
        assert client.post("/v2/notify", json=NOTE, headers={"X-Api-Key": key}).status_code == 200
        reader = issuer.token(aud=AUD, scope="read")
        assert client.get("/v2/entities", headers=bearer(reader)).json()[0]["id"] == "r1"
