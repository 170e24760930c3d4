"""``/openapi.json`` declares security exactly when the service asks for a
credential: with no API key and no token setting (the default) it declares
no scheme, no requirement and no 401/403 answer, so ``/docs`` shows no lock
and no *Authorize* button; with keys or tokens every route requires one of
the two schemes, except the open ``/health`` and ``/version``."""

from __future__ import annotations

import pytest

KEY = "openapi-reader-key-0001:read"
JWT_SECRET = "openapi-secret-openapi-secret-32"


def _operations(doc):
    for path, item in doc["paths"].items():
        for method, operation in item.items():
            yield path, method, operation


@pytest.fixture(scope="module")
def db(tmp_path_factory) -> str:
    return str(tmp_path_factory.mktemp("openapi-security") / "tsdb.duckdb")


def test_no_security_is_declared_while_authentication_is_off(app_factory, db):
    doc = app_factory(db).openapi()
    assert "securitySchemes" not in doc["components"]
    assert "security" not in doc
    for path, method, operation in _operations(doc):
        assert "security" not in operation, (path, method)
        assert not {"401", "403"} & set(operation["responses"]), (path, method)


@pytest.mark.parametrize(
    "settings",
    [{"api_keys": KEY}, {"jwt_key": JWT_SECRET}, {"api_keys": KEY, "api_key_header": "X-Orion-Key"}],
    ids=["keys", "jwt", "key-header"],
)
def test_a_credential_is_required_while_authentication_is_on(app_factory, db, settings):
    doc = app_factory(db, **settings).openapi()
    schemes = doc["components"]["securitySchemes"]
    header = settings.get("api_key_header", "X-Api-Key")
    assert schemes["ApiKeyHeader"] == {**schemes["ApiKeyHeader"], "type": "apiKey", "in": "header", "name": header}
    assert schemes["Bearer"] == {**schemes["Bearer"], "type": "http", "scheme": "bearer"}
    assert doc["security"] == [{"ApiKeyHeader": []}, {"Bearer": []}]  # one of them, never none
    for path in ("/health", "/version"):
        assert doc["paths"][path]["get"]["security"] == [{}], path
    entities = doc["paths"]["/v2/entities"]["get"]
    assert "security" not in entities and {"401", "403"} <= set(entities["responses"])


def test_the_served_document_follows_the_settings(client_factory, db):
    with client_factory(db) as client:
        assert "securitySchemes" not in client.get("/openapi.json").json()["components"]
    with client_factory(db, api_keys=KEY) as client:
        served = client.get("/openapi.json")  # an open path: readable without a credential
        assert served.status_code == 200 and "securitySchemes" in served.json()["components"]
