"""``/openapi.json`` describes what is served: every route, every parameter
the parsers read, JSON answers typed as JSON, errors in the NGSI shape.
(The fuzz job checks the answers against it; ``test_openapi_security``
what it says about credentials.)"""

from __future__ import annotations

import re

import pytest

from tsdb_service.faces.export.query import PARAMETERS as EXPORT_PARAMETERS

HISTORY_QUERY = {
    "attrs",
    "fromDate",
    "toDate",
    "lastN",
    "limit",
    "offset",
    "aggrMethod",
    "aggrPeriod",
    "aggrScope",
    "options",
    "georel",
    "geometry",
    "coords",
}
TENANCY = {"Fiware-Service", "NGSILD-Tenant", "Fiware-ServicePath"}
NOTIFY_HEADERS = {
    "Fiware-Service",
    "Fiware-ServicePath",
    "NGSILD-Tenant",
    "Ngsiv2-AttrsFormat",
    "Ngsild-Attribute-Format",
    "Fiware-TimeIndex-Attribute",
}


@pytest.fixture(scope="module")
def doc(app_factory, tmp_path_factory):
    """The description needs no store: the app is built, not started."""
    return app_factory(str(tmp_path_factory.mktemp("openapi") / "tsdb.duckdb")).openapi()


def _names(operation, where):
    return {p["name"] for p in operation.get("parameters", []) if p["in"] == where}


def _flat(routes):
    """Routes of included routers too (FastAPI keeps them per router)."""
    for route in routes:
        inner = getattr(route, "original_router", None)
        yield from _flat(inner.routes) if inner is not None else (route,)


def _operations(doc):
    for path, item in doc["paths"].items():
        for method, operation in item.items():
            yield path, method, operation


def _without_convertors(path: str) -> str:
    """``{entity_id:segment}`` as OpenAPI writes it: ``{entity_id}``."""
    return re.sub(r"\{(\w+):\w+\}", r"{\1}", path)


def test_every_served_route_is_described(doc, app_factory, tmp_path):
    app = app_factory(str(tmp_path / "tsdb.duckdb"))
    served = {
        (_without_convertors(route.path), method.lower())
        for route in _flat(app.routes)
        if getattr(route, "include_in_schema", False)
        for method in route.methods - {"HEAD"}
    }
    described = {(path, method) for path, method, _ in _operations(doc)}
    assert served == described


@pytest.mark.parametrize(
    "path",
    [
        "/v2/entities/{entity_id}",
        "/v2/entities/{entity_id}/value",
        "/v2/entities/{entity_id}/attrs/{attr_name}",
        "/v2/types/{entity_type}",
        "/v2/types/{entity_type}/attrs/{attr_name}/value",
        "/v2/attrs",
        "/v2/attrs/value",
        "/v2/attrs/{attr_name}",
        "/v2/attrs/{attr_name}/value",
    ],
)
def test_history_routes_declare_every_parameter_they_read(doc, path):
    operation = doc["paths"][path]["get"]
    assert _names(operation, "query") >= HISTORY_QUERY
    assert _names(operation, "header") >= TENANCY
    assert {"lastN", "limit", "offset"} <= {
        p["name"]
        for p in operation["parameters"]
        if p["schema"].get("type") == "integer" and p["schema"]["minimum"] >= 0
    }
    enum = {p["name"]: p["schema"].get("enum") for p in operation["parameters"]}
    assert enum["aggrMethod"] == ["count", "sum", "avg", "min", "max"]


def test_export_declares_exactly_what_it_accepts(doc):
    operation = doc["paths"]["/v2/export"]["get"]
    assert _names(operation, "query") == set(EXPORT_PARAMETERS)
    assert set(operation["responses"]["200"]["content"]) == {
        "text/csv",
        "application/vnd.apache.parquet",
        "application/x-mcap",
    }


@pytest.mark.parametrize("path", ["/v2/notify", "/ngsi-ld/v1/notify"])
def test_notify_declares_its_headers_and_bodies(doc, path):
    operation = doc["paths"][path]["post"]
    assert _names(operation, "header") == NOTIFY_HEADERS
    body = operation["requestBody"]
    assert set(body["content"]) == {"application/json", "application/ld+json", "application/geo+json"}
    assert body["content"]["application/json"]["schema"] == {"$ref": "#/components/schemas/Notification"}
    assert {"400", "413", "415"} <= set(operation["responses"])


def test_json_answers_are_typed_and_errors_are_ngsi(doc):
    error = {"$ref": "#/components/schemas/NgsiError"}
    for path, method, operation in _operations(doc):
        for status, response in operation["responses"].items():
            content = response.get("content", {})
            ld_api = path.startswith("/ngsi-ld/") and not path.endswith("/notify")  # ProblemDetails there
            if status.startswith(("4", "5")) and not (path == "/health" and status == "503") and not ld_api:
                assert content == {"application/json": {"schema": error}}, (path, method, status)
            elif "application/json" in content and path not in ("/v2/notify", "/ngsi-ld/v1/notify"):
                assert content["application/json"]["schema"].get("type") != "string", (path, method, status)


def test_content_types_of_non_json_answers(doc):
    assert set(doc["paths"]["/metrics"]["get"]["responses"]["200"]["content"]) == {"text/plain"}
    assert set(doc["paths"]["/health"]["get"]["responses"]["200"]["content"]) == {"application/health+json"}
    assert set(doc["paths"]["/ui/"]["get"]["responses"]["200"]["content"]) == {"text/html"}


def test_no_framework_validation_answer_is_described(doc):
    """Validation errors are answered 400 in the NGSI shape, never FastAPI's 422."""
    assert "HTTPValidationError" not in doc["components"]["schemas"]
    for path, method, operation in _operations(doc):
        schema = operation["responses"].get("422", {}).get("content", {}).get("application/json", {}).get("schema")
        allowed = [None, {"$ref": "#/components/schemas/NgsiError"}]
        if path.startswith("/ngsi-ld/") and not path.endswith("/notify"):
            allowed.append({"$ref": "#/components/schemas/ProblemDetails"})  # TooComplexQuery there
        assert schema in allowed, (path, method)


def test_the_served_document_is_the_completed_one(client):
    served = client.get("/openapi.json").json()
    assert "NgsiError" in served["components"]["schemas"]
    assert served == client.app.openapi()
