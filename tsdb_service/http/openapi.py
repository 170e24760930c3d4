"""The OpenAPI description's shared pieces: parameters, bodies, answers.

Routes read their query parameters and headers from the request on purpose
(``faces.quantumleap.params`` and friends parse them once, in plain Python, and are the
one source of validation and of the NGSI error answers), so FastAPI cannot
infer them from the signatures. Each route instead declares them here,
through ``openapi_extra`` and ``responses``: the description is generated
from the same code that is served, and nothing here runs per request.

``install`` completes the document once, when it is first asked for: the
component schemas the routes refer to, the security schemes when
authentication is on (and none, nor any 401 or 403 answer, when it is off),
and no trace of FastAPI's own 422 validation answer (our handler answers 400).
Bounds and enumerations mirror the parsers; where a parser is more lenient
(case-insensitive keywords, say), the description documents the canonical
spelling.
"""

from __future__ import annotations

from typing import Any

REF = "#/components/schemas/"

# --- JSON schema building blocks -------------------------------------------------------------------


def ref(name: str) -> dict:
    return {"$ref": REF + name}


def obj(required: tuple[str, ...], props: dict, *, extra: Any = False, description: str | None = None) -> dict:
    schema: dict[str, Any] = {"type": "object", "required": list(required), "properties": props}
    if extra is not True:
        schema["additionalProperties"] = extra
    if description:
        schema["description"] = description
    return schema


def array(items: dict, description: str | None = None) -> dict:
    schema: dict[str, Any] = {"type": "array", "items": items}
    if description:
        schema["description"] = description
    return schema


STR = {"type": "string"}
STRS = array(STR)
NULLABLE_STR = {"type": ["string", "null"]}
ANY: dict = {}


SCHEMAS: dict[str, dict] = {
    "NgsiError": obj(
        ("error", "description"),
        {"error": STR, "description": STR},
        description="Every error answer: an NGSI error name and a human description.",
    ),
    "ProblemDetails": obj(
        ("type", "title"),
        {"type": STR, "title": STR, "status": {"type": "integer"}, "detail": STR, "instance": STR},
        extra=True,
        description="NGSI-LD errors (RFC 7807), for NGSI-LD API routes other than notify",
    ),
    "EntityLD": obj(("id",), {"id": STR, "type": {"anyOf": [STR, STRS]}, "@context": ANY}, extra=True),
}


# --- responses -------------------------------------------------------------------------------------

_ERROR_TEXT = {
    400: "Bad request: a parameter, header or body is invalid",
    401: "No or invalid credential",
    403: "The credential lacks the scope or tenant this request needs",
    404: "Nothing matched, or no such resource",
    409: "Ambiguous: the entity id exists in several types",
    413: "The body exceeds the size limit (kept in the rejected store)",
    406: "None of the accepted media types can be answered (NGSI-LD: application/json or application/ld+json)",
    415: "Not a JSON media type (kept in the rejected store)",
    422: "The query would exceed a read budget (QueryTooLarge): narrow it",
    502: "The broker answered with an error",
    503: "The store is unavailable; retry later",
}
AUTH = (401, 403)
READ_ERRORS = (400, *AUTH, 422, 503)


def errors(*codes: int) -> dict[int, dict]:
    return {
        code: {"description": _ERROR_TEXT[code], "content": {"application/json": {"schema": ref("NgsiError")}}}
        for code in codes
    }


def ld_errors(*codes: int) -> dict[int, dict]:
    """Error answers of NGSI-LD API routes: ProblemDetails (RFC 7807)."""
    problem = {"schema": ref("ProblemDetails")}
    return {
        code: {
            "description": _ERROR_TEXT[code],
            "content": {"application/json": problem, "application/problem+json": problem},
        }
        for code in codes
    }


def ok(
    schema: dict, description: str = "Success", media_type: str = "application/json", status: int = 200
) -> dict[int, dict]:
    return {status: {"description": description, "content": {media_type: {"schema": schema}}}}


def ref_array(name: str) -> dict:
    return array(ref(name))


# --- parameters ------------------------------------------------------------------------------------


def _param(where: str, name: str, description: str, schema: dict | None = None, required: bool = False) -> dict:
    return {
        "name": name,
        "in": where,
        "required": required,
        "description": description,
        "schema": schema or {"type": "string"},
    }


def query(name: str, description: str, schema: dict | None = None, required: bool = False) -> dict:
    return _param("query", name, description, schema, required)


def header(name: str, description: str, schema: dict | None = None) -> dict:
    return _param("header", name, description, schema)


TENANT_SCHEMA = {"type": "string", "pattern": "^[A-Za-z0-9_]{0,50}$"}
# Service paths: /a/b; a query may list several (comma-separated, at most 50)
# and end one in /# for a subtree. Components are 1 to 256 characters, no
# whitespace or '#'. The patterns stay simple (the parser has the last word).
SP_QUERY = {"type": "string", "pattern": r"^(/[^#\s,]*(/#)?|#)(,\s*/[^#\s,]*(/#)?)*$"}

FIWARE_SERVICE = header("Fiware-Service", "Tenant (Orion lower-cases it); none is the default tenant.", TENANT_SCHEMA)
NGSILD_TENANT = header(
    "NGSILD-Tenant", "NGSI-LD tenant; must agree with Fiware-Service when both are given.", TENANT_SCHEMA
)
SERVICE_PATH_QUERY = header(
    "Fiware-ServicePath",
    "Service paths to read: comma list, /# for a subtree; none or / is the whole tenant.",
    SP_QUERY,
)
TENANCY = [FIWARE_SERVICE, NGSILD_TENANT, SERVICE_PATH_QUERY]

INT_MAX = 10**18 - 1  # faces/quantumleap/params.py: at most 18 digits
POSITIVE = {"type": "integer", "minimum": 1, "maximum": INT_MAX}
TIME = {"type": "string", "format": "date-time"}

ID = query("id", "Entity ids, comma-separated.")
TYPE = query("type", "Entity types, comma-separated.")
ID_PATTERN = query("idPattern", "Entity id regular expression (RE2 syntax, searched, linear time).")
ATTRS = query("attrs", "Attribute names or value paths (odom(twist.linear.x)), comma-separated.")
FROM_DATE = query("fromDate", "Oldest time index, inclusive (ISO 8601; naive means UTC).", TIME)
TO_DATE = query("toDate", "Newest time index, inclusive (ISO 8601; naive means UTC).", TIME)
LIMIT = query("limit", "At most this many rows (capped by the server's default limit).", POSITIVE)
OFFSET = query("offset", "Rows to skip.", {"type": "integer", "minimum": 0, "maximum": INT_MAX})
GEO = [
    query(
        "georel",
        "NGSIv2 geo relation: near;maxDistance:M;minDistance:M, coveredBy, intersects, equals, disjoint.",
        {"type": "string", "pattern": "^(near|coveredBy|intersects|equals|disjoint)(;.*)?$"},
    ),
    query("geometry", "Shape of coords.", {"enum": ["point", "line", "polygon", "box"]}),
    query("coords", "lat,lon pairs separated by ';'."),
]


def params(*parameters: dict) -> dict:
    """``openapi_extra`` declaring ``parameters`` (appended to the path's own)."""
    return {"parameters": list(parameters)}


def json_body(
    schema: dict,
    *,
    required: bool = True,
    media_types: tuple[str, ...] = ("application/json",),
    examples: dict | None = None,
) -> dict:
    """``openapi_extra`` fragment declaring a JSON request body."""
    content = {}
    for media in media_types:
        content[media] = {"schema": schema}
        if examples:
            content[media]["examples"] = {name: {"value": value} for name, value in examples.items()}
    return {"requestBody": {"required": required, "content": content}}


def spec(*parameters: dict, ok_: dict[int, dict], errors_: tuple[int, ...], body: dict | None = None) -> dict:
    """Keyword arguments for a route decorator: no inferred response model,
    the documented answers and the declared parameters (and body)."""
    extra: dict[str, Any] = {}
    if parameters:
        extra["parameters"] = list(parameters)
    if body:
        extra.update(body)
    out: dict[str, Any] = {"response_model": None, "responses": {**ok_, **errors(*errors_)}}
    if extra:
        out["openapi_extra"] = extra
    return out


# --- the whole document ----------------------------------------------------------------------------

OPEN = ("/health", "/version")  # security.guard.OPEN_PATHS: never need a credential


def security_schemes(api_key_header: str) -> dict:
    return {
        "ApiKeyHeader": {
            "type": "apiKey",
            "in": "header",
            "name": api_key_header,
            "description": "An API key (TSDB_API_KEYS, TSDB_API_KEYS_FILE).",
        },
        "Bearer": {
            "type": "http",
            "scheme": "bearer",
            "bearerFormat": "API key or JWT",
            "description": "An API key, or an OAuth2 JWT (Keyrock, Keycloak) when TSDB_JWT_* is set.",
        },
    }


def complete(doc: dict, api_key_header: str | None, schemas_of_features: dict[str, dict] | None = None) -> dict:
    """Add the component schemas (the kit's and each feature's) and, when
    authentication is on (``api_key_header`` names the key header), the
    security schemes every route but the open ones requires; drop FastAPI's
    422 validation answer, which this service never sends.

    With authentication off the document declares no security at all, so
    Swagger UI shows no lock and no *Authorize* button for a credential the
    service would not ask for."""
    components = doc.setdefault("components", {})
    schemas = components.setdefault("schemas", {})
    for name in ("HTTPValidationError", "ValidationError"):
        schemas.pop(name, None)
    schemas.update(SCHEMAS)
    schemas.update(schemas_of_features or {})
    if api_key_header is not None:
        components["securitySchemes"] = security_schemes(api_key_header)
        doc["security"] = [{"ApiKeyHeader": []}, {"Bearer": []}]
    for path, item in doc.get("paths", {}).items():
        for operation in item.values():
            responses = operation.get("responses", {})
            if _is_validation_error(responses.get("422")):
                del responses["422"]
            for response in responses.values():
                _drop_placeholder(response.get("content"))
            if api_key_header is None:
                for code in AUTH:
                    responses.pop(str(code), None)
            elif path in OPEN:
                operation["security"] = [{}]
    return doc


def _drop_placeholder(content: dict | None) -> None:
    """FastAPI adds ``application/json`` with an empty schema for the default
    response class; a route that declared its own media type answers only that."""
    if content and len(content) > 1 and content.get("application/json") == {"schema": {}}:
        del content["application/json"]


def _is_validation_error(response: dict | None) -> bool:
    if not response:
        return False
    schema = response.get("content", {}).get("application/json", {}).get("schema", {})
    return schema.get("$ref", "").endswith("/HTTPValidationError")


def install(app, api_key_header: str | None, schemas: dict[str, dict] | None = None) -> None:
    """Make ``FastAPI.openapi()`` return the completed document (built once);
    ``api_key_header``: the API key header when authentication is on, None
    when it is off; ``schemas``: the features' component schemas (each
    feature's ``openapi.SCHEMAS``)."""
    generate = app.openapi
    done: list[dict] = []

    def openapi() -> dict:
        if not done:
            done.append(complete(generate(), api_key_header, schemas))
        return done[0]

    app.openapi = openapi


# --- per-route declarations -------------------------------------------------------------------------


def with_headers(operation: dict, headers: dict, status: int = 200) -> dict:
    """``operation`` (a ``spec``) with ``headers`` declared on its ``status`` answer."""
    operation["responses"][status]["headers"] = headers
    return operation


# --- Grafana ---------------------------------------------------------------------------------------


NULLABLE_STR = {"type": ["string", "null"]}

# --- the explorer ------------------------------------------------------------------------------------
