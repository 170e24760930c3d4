"""API keys: scopes (read, write, admin), tenant restrictions, where a key
may travel, and the 401/403 answers, on the fast notification path and the
framework routes alike. Off by default: see ``test_off_by_default``."""

from __future__ import annotations

import hashlib

import pytest

from tsdb_service.app import create_app
from tsdb_service.core.config import Settings
from tsdb_service.security import ADMIN as ADMIN_SCOPE
from tsdb_service.security import METRICS, READ, WRITE, required_scope
from tsdb_service.security.guard import route_path

READER, WRITER, ADMIN = "reader-0123456789abcdef", "writer-0123456789abcdef", "admin-0123456789abcdef"
ACME_WRITER, DEFAULT_READER = "acme-writer-0123456789", "default-reader-0123456789"
KEYS = f"{READER}:read; {WRITER}:write {ADMIN}:admin;{ACME_WRITER}:write,read:ACME,other_co  {DEFAULT_READER}:read:-"


def note(eid: str = "r1") -> dict:
    return {
        "data": [
            {
                "id": eid,
                "type": "Robot",
                "TimeInstant": {"type": "DateTime", "value": "2024-05-01T00:00:00Z"},
                "battery": {"type": "Number", "value": 80},
            }
        ]
    }


def bearer(key: str, **extra) -> dict:
    return {"Authorization": f"Bearer {key}", **extra}


@pytest.fixture
def embedded_db(tmp_path) -> str:
    """The guard answers before any storage is touched, so most tests here
    need one backend: an embedded DuckDB file. Those whose outcome is what
    got stored (or not) run on both."""
    return str(tmp_path / "tsdb.duckdb")


@pytest.fixture
def secured(client_factory, embedded_db):
    with client_factory(embedded_db, api_keys=KEYS) as client:
        yield client


@pytest.fixture
def secured_store(client_factory, store_url):
    with client_factory(store_url, api_keys=KEYS) as client:
        yield client


def test_off_by_default(embedded_db):
    app = create_app(Settings(db=embedded_db))
    assert app.front == app.dispatch  # nothing in front of the routes: no cost


def test_missing_credential_is_401_with_a_challenge_everywhere(secured):
    for method, path in [
        ("POST", "/v2/notify"),
        ("POST", "/ngsi-ld/v1/notify"),
        ("GET", "/v2/entities"),
        ("POST", "/grafana/simplejson/query"),
        ("GET", "/no/such/path"),
    ]:
        response = secured.request(method, path, json=note())
        assert response.status_code == 401, (path, response.text)
        assert response.headers["www-authenticate"] == 'Bearer realm="tsdb-service"'
        assert response.json()["error"] == "Unauthorized" and set(response.json()) == {"error", "description"}


@pytest.mark.parametrize(
    "auth", ["Bearer not-a-configured-key-at-all", "Basic cmVhZGVyOnB3", "Bearer ", "Bearer a.b.c", "Bearer"]
)
def test_invalid_credential_is_401_invalid_token(secured, auth):
    response = secured.get("/v2/entities", headers={"Authorization": auth})
    assert response.status_code == 401
    assert 'error="invalid_token"' in response.headers["www-authenticate"]


def test_health_version_and_docs_stay_open(secured):
    for path in ("/health", "/version", "/openapi.json"):
        assert secured.get(path).status_code == 200, path


def test_scopes(secured):
    assert secured.post("/v2/notify", json=note(), headers=bearer(WRITER)).status_code == 200
    assert secured.post("/v2/notify", json=note(), headers=bearer(READER)).status_code == 403
    assert secured.get("/v2/entities", headers=bearer(WRITER)).status_code == 403  # write is not read
    assert secured.get("/v2/entities", headers=bearer(READER)).json()[0]["id"] == "r1"
    assert secured.post("/v2/op/query", json={"entities": [{"id": "r1"}]}, headers=bearer(READER)).status_code == 200
    grafana = secured.post("/grafana/simplejson/search", json={"target": ""}, headers=bearer(READER))
    assert grafana.status_code == 200
    subscription = {"attrs": ["id", "battery"], "entityType": "Robot"}
    assert secured.put("/v2/notify/subscriptions/s1", json=subscription, headers=bearer(READER)).status_code == 403
    assert secured.put("/v2/notify/subscriptions/s1", json=subscription, headers=bearer(WRITER)).status_code == 200


@pytest.mark.parametrize(
    ("method", "path", "status"),
    [("DELETE", "/v2/entities/r1", 204), ("DELETE", "/v2/types/Robot", 204), ("GET", "/v2/notify/rejected", 200)],
)
def test_deletes_and_the_rejected_store_need_admin(secured_store, method, path, status):
    secured = secured_store
    secured.post("/v2/notify", json=note(), headers=bearer(WRITER))
    for key in (READER, WRITER, ACME_WRITER):
        refused = secured.request(method, path, headers=bearer(key))
        assert refused.status_code == 403, key
        assert 'error="insufficient_scope"' in refused.headers["www-authenticate"]
        assert refused.json()["error"] == "Forbidden"
    assert secured.request(method, path, headers=bearer(ADMIN)).status_code == status


def test_admin_implies_read_and_write(secured):
    assert secured.post("/v2/notify", json=note(), headers=bearer(ADMIN)).status_code == 200
    assert secured.get("/v2/entities/r1", headers=bearer(ADMIN)).status_code == 200


def test_key_header_and_a_custom_one(client_factory, embedded_db):
    with client_factory(embedded_db, api_keys=KEYS) as client:
        assert client.post("/v2/notify", json=note(), headers={"X-Api-Key": WRITER}).status_code == 200
    with client_factory(embedded_db, api_keys=KEYS, api_key_header="X-Orion-Key") as client:
        assert client.post("/v2/notify", json=note(), headers={"X-Orion-Key": WRITER}).status_code == 200
        assert client.post("/v2/notify", json=note(), headers={"X-Api-Key": WRITER}).status_code == 401


def test_two_different_credentials_are_refused(secured):
    response = secured.get("/v2/entities", headers={**bearer(READER), "X-Api-Key": ADMIN})
    assert response.status_code == 401


def test_tenant_restricted_key(secured):
    acme = bearer(ACME_WRITER, **{"Fiware-Service": "acme"})
    assert secured.post("/v2/notify", json=note(), headers=acme).status_code == 200
    assert secured.get("/v2/entities", headers=bearer(ACME_WRITER, **{"Fiware-Service": "ACME"})).status_code == 200
    ld = bearer(ACME_WRITER, **{"NGSILD-Tenant": "other_co"})
    assert secured.get("/v2/entities", headers=ld).status_code == 200
    for headers in (
        {"Fiware-Service": "evil"},
        {},
        {"Fiware-Service": ""},
        {"Fiware-Service": "acme", "NGSILD-Tenant": "evil"},
    ):
        response = secured.post("/v2/notify", json=note(), headers=bearer(ACME_WRITER, **headers))
        assert response.status_code == 403, headers
        assert "tenant" in response.json()["description"]
    grafana = secured.get("/grafana/infinity/entities", params={"service": "evil"}, headers=acme)
    assert grafana.status_code == 403
    assert secured.get("/grafana/infinity/entities", params={"service": "acme"}, headers=acme).status_code == 200


def test_refused_tenant_leaves_nothing_behind(secured_store):
    secured = secured_store
    evil = bearer(ACME_WRITER, **{"Fiware-Service": "evil"})
    assert secured.post("/v2/notify", json=note(), headers=evil).status_code == 403
    broken = secured.post("/v2/notify", content=b"{broken", headers={"Content-Type": "application/json"})
    assert broken.status_code == 401
    admin = bearer(ADMIN, **{"Fiware-Service": "evil"})
    assert secured.get("/v2/entities", headers=admin).json() == []
    assert secured.get("/v2/notify/rejected", headers=admin).json() == []
    assert secured.get("/v2/notify/rejected", headers=bearer(ADMIN)).json() == []


def test_default_tenant_token(secured):
    assert secured.get("/v2/entities", headers=bearer(DEFAULT_READER)).status_code == 200
    assert secured.get("/v2/entities", headers=bearer(DEFAULT_READER, **{"Fiware-Service": "acme"})).status_code == 403


def test_keys_file_holds_only_digests(client_factory, embedded_db, tmp_path):
    digest = hashlib.sha256(WRITER.encode()).hexdigest()
    keys_file = tmp_path / "keys"
    reader = hashlib.sha256(READER.encode()).hexdigest()
    keys_file.write_text(f"# orion\n{digest} write acme   # the broker\n\n{reader} read\n")
    with client_factory(embedded_db, api_keys_file=str(keys_file)) as client:
        acme = bearer(WRITER, **{"Fiware-Service": "acme"})
        assert client.post("/v2/notify", json=note(), headers=acme).status_code == 200
        assert client.get("/v2/entities", headers=bearer(READER, **{"Fiware-Service": "acme"})).status_code == 200
        assert client.get("/v2/entities", headers=bearer(digest)).status_code == 401  # the digest is no key


@pytest.mark.parametrize(
    ("settings", "message"),
    [
        ({"api_keys": "short:read"}, "at least 16"),
        ({"api_keys": "long-enough-key-1234:superuser"}, "read, write, admin"),
        ({"api_keys": "long-enough-key-1234"}, "read, write, admin"),
        ({"api_keys_file": "/nonexistent/keys"}, "cannot read"),
        ({"jwt_key": "secret-secret-secret-secret-32b!", "jwt_algorithms": "RS256"}, "cannot be used"),
        ({"jwt_key": "s" * 32, "jwt_jwks_url": "http://127.0.0.1:9/certs"}, "not both"),
    ],
)
def test_bad_configuration_refuses_to_start(tmp_path, settings, message):
    with pytest.raises(ValueError, match=message):
        create_app(Settings(db=str(tmp_path / "db.duckdb"), **settings))


def test_bad_keys_file_line(tmp_path):
    keys_file = tmp_path / "keys"
    keys_file.write_text("not-a-digest read\n")
    with pytest.raises(ValueError, match="keys line 1"):
        create_app(Settings(db=str(tmp_path / "db.duckdb"), api_keys_file=str(keys_file)))


@pytest.mark.parametrize(
    ("method", "path", "scope"),
    [
        ("POST", "/v2/notify", WRITE),
        ("POST", "/ngsi-ld/v1/notify", WRITE),
        ("PUT", "/v2/notify/subscriptions/s1", WRITE),
        ("GET", "/v2/notify/subscriptions", READ),
        ("GET", "/v2/notify/rejected", ADMIN_SCOPE),
        ("GET", "/v2/notify/rejected/", ADMIN_SCOPE),
        ("POST", "/v2/op/query", READ),
        ("POST", "/grafana/simplejson/query", READ),
        ("GET", "/grafana/infinity/series", READ),
        ("DELETE", "/v2/entities/r1", ADMIN_SCOPE),
        ("DELETE", "/v2/types/Robot", ADMIN_SCOPE),
        ("PATCH", "/anything", ADMIN_SCOPE),
        ("GET", "/metrics", METRICS),
        ("GET", "/ngsi-ld/v1/temporal/entities", READ),
        ("POST", "/ngsi-ld/v1/temporal/entityOperations/query", READ),
        ("POST", "/ngsi-ld/v1/temporal/entities", WRITE),
        ("PATCH", "/ngsi-ld/v1/temporal/entities/e1/attrs/speed/i1", ADMIN_SCOPE),
        ("DELETE", "/ngsi-ld/v1/temporal/entities/e1", ADMIN_SCOPE),
    ],
)
def test_required_scope(method, path, scope):
    assert required_scope(method, path) == scope


def test_a_mount_prefix_cannot_dodge_the_rules():
    scope = {"path": "/tsdb/v2/notify/rejected", "root_path": "/tsdb"}
    assert required_scope("GET", route_path(scope)) == ADMIN_SCOPE


def test_a_key_that_looks_like_a_jwt_is_still_a_key(client_factory, embedded_db):
    dotted = "abc.defghijklmnop.qrstuvw"
    with client_factory(embedded_db, api_keys=f"{dotted}:read", jwt_key="s" * 32) as client:
        assert client.get("/v2/entities", headers=bearer(dotted)).status_code == 200
