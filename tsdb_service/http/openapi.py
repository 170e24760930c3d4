"""The OpenAPI description's shared pieces: parameters, bodies, answers.

Routes read their query parameters and headers from the request on purpose
(``history.params`` and friends parse them once, in plain Python, and are the
one source of validation and of the NGSI error answers), so FastAPI cannot
infer them from the signatures. Each route instead declares them here,
through ``openapi_extra`` and ``responses``: the description is generated
from the same code that is served, and nothing here runs per request.

``install`` completes the document once, when it is first asked for: the
component schemas the routes refer to, the optional security schemes, and
no trace of FastAPI's own 422 validation answer (our handler answers 400).
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


def _obj(required: tuple[str, ...], props: dict, *, extra: Any = False, description: str | None = None) -> dict:
    schema: dict[str, Any] = {"type": "object", "required": list(required), "properties": props}
    if extra is not True:
        schema["additionalProperties"] = extra
    if description:
        schema["description"] = description
    return schema


def _array(items: dict, description: str | None = None) -> dict:
    schema: dict[str, Any] = {"type": "array", "items": items}
    if description:
        schema["description"] = description
    return schema


_STR = {"type": "string"}
_STRS = _array(_STR)
_NULLABLE_STR = {"type": ["string", "null"]}
_ANY: dict = {}
_INDEX = _array(_STR, "time indices, UTC ISO 8601 with milliseconds (2024-05-01T10:00:00.123+00:00)")
_VALUES = _array(_ANY, "values, parallel to index")
_EMPTY = {"type": "array", "maxItems": 0, "description": "nothing matched"}
_ONE_HEAD = [{"required": ["id"]}, {"required": ["ids"]}]  # ids: aggrScope=global

_ATTR_VALUES = _obj(("attrName", "values"), {"attrName": _STR, "values": _VALUES})
_TYPE_ENTITY = _obj(
    ("index", "attributes"), {"id": _STR, "ids": _STRS, "index": _INDEX, "attributes": _array(_ATTR_VALUES)}
)
_TYPE_ENTITY["anyOf"] = _ONE_HEAD
_TYPE_ATTR_ENTITY = _obj(("index", "values"), {"id": _STR, "ids": _STRS, "index": _INDEX, "values": _VALUES})
_TYPE_ATTR_ENTITY["anyOf"] = _ONE_HEAD
_ATTR_TYPE = {
    **_obj(("entities",), {"type": _STR, "types": _STRS, "entities": _array(ref("TypeAttrEntity"))}),
    "anyOf": [{"required": ["type"]}, {"required": ["types"]}],
}
_ATTR_TYPES = _obj(("attrName", "types"), {"attrName": _STR, "types": _array(ref("AttrTypeGroup"))})

_FRAME_FIELD = _obj(
    ("name", "type", "values"), {"name": _STR, "type": _STR, "values": _array(_ANY), "labels": {"type": "object"}}
)

SCHEMAS: dict[str, dict] = {
    "NgsiError": _obj(
        ("error", "description"),
        {"error": _STR, "description": _STR},
        description="Every error answer: an NGSI error name and a human description.",
    ),
    "ProblemDetails": _obj(
        ("type", "title"),
        {"type": _STR, "title": _STR, "status": {"type": "integer"}, "detail": _STR, "instance": _STR},
        extra=True,
        description="NGSI-LD errors (RFC 7807), for NGSI-LD API routes other than notify",
    ),
    # history (QuantumLeap 1.0 shapes; see history.shape)
    "EntityAttrHistory": _obj(
        ("id", "type", "attrName", "index", "values"),
        {"id": _STR, "type": _STR, "attrName": _STR, "index": _INDEX, "values": _VALUES},
    ),
    "EntityAttrValues": _obj(("index", "values"), {"index": _INDEX, "values": _VALUES}),
    "EntityHistory": _obj(
        ("id", "type", "index", "attributes"),
        {"id": _STR, "type": _STR, "index": _INDEX, "attributes": _array(_ATTR_VALUES)},
    ),
    "EntityValues": _obj(("index", "attributes"), {"index": _INDEX, "attributes": _array(_ATTR_VALUES)}),
    "TypeEntity": _TYPE_ENTITY,
    "TypeAttrEntity": _TYPE_ATTR_ENTITY,
    "TypeHistory": _obj(("type", "entities"), {"type": _STR, "entities": _array(ref("TypeEntity"))}),
    "TypeValues": _obj(("values",), {"values": _array(ref("TypeEntity"))}),
    "TypeAttrHistory": _obj(
        ("type", "attrName", "entities"), {"type": _STR, "attrName": _STR, "entities": _array(ref("TypeAttrEntity"))}
    ),
    "TypeAttrValues": _obj(("values",), {"values": _array(ref("TypeAttrEntity"))}),
    "AttrTypeGroup": _ATTR_TYPE,
    "AttrHistory": _obj(("attrName", "types"), {"attrName": _STR, "types": _array(ref("AttrTypeGroup"))}),
    "AttrValues": _obj(("values",), {"values": _array(ref("AttrTypeGroup"))}),
    "AttrsHistory": _obj(("attrs",), {"attrs": _array(_ATTR_TYPES)}),
    "AttrsValues": _obj(("values",), {"values": _array(_ATTR_TYPES)}),
    "EntityListItem": _obj(("id", "type", "index"), {"id": _STR, "type": _STR, "index": _STR}),
    "LastValueEntity": _obj(
        ("id", "type", "dateModified"),
        {"id": _STR, "type": _STR},
        extra=_obj(("type", "value"), {"type": _STR, "value": _ANY}),
        description="An entity at its latest values, NGSIv2 normalized form",
    ),
    # notifications
    "NotificationV2": _obj(
        ("data",),
        {
            "subscriptionId": _STR,
            "data": _array({"anyOf": [ref("EntityV2"), _array(_ANY, "a row of Orion's 'values' format")]}),
        },
        extra=True,
        description="NGSIv2 notification (normalized, keyValues or values: Ngsiv2-AttrsFormat)",
    ),
    "EntityV2": _obj(
        ("id",),
        {"id": _STR, "type": _STR},
        extra=True,
        description="An NGSIv2 entity: {name: {type, value, metadata}} or, keyValues, {name: value}",
    ),
    "NotificationLD": _obj(
        ("type", "data"),
        {
            "id": _STR,
            "type": {"const": "Notification"},
            "subscriptionId": _STR,
            "notifiedAt": _STR,
            "data": {
                "anyOf": [
                    _array(ref("EntityLD")),
                    _obj(
                        ("type",),
                        {"type": {"enum": ["FeatureCollection", "Feature"]}},
                        extra=True,
                        description="GeoJSON (application/geo+json)",
                    ),
                ]
            },
        },
        extra=True,
        description="NGSI-LD notification (normalized, concise or simplified: Ngsild-Attribute-Format)",
    ),
    "EntityLD": _obj(("id",), {"id": _STR, "type": {"anyOf": [_STR, _STRS]}, "@context": _ANY}, extra=True),
    "NotificationV1": _obj(
        ("contextResponses",),
        {"subscriptionId": _STR, "originator": _STR, "contextResponses": _array({"type": "object"})},
        extra=True,
        description="NGSIv1 notification (Orion 'legacy' format)",
    ),
    "Notification": {
        "anyOf": [ref("NotificationV2"), ref("NotificationLD"), ref("NotificationV1"), ref("EntityV2")],
        "description": "Any notification a broker sends; the bare entity is Orion's simplified "
        "formats. Open: unknown members are ignored or stored as attributes.",
    },
    "ValuesLayout": _obj(
        ("attrs", "entityId", "entityType"), {"attrs": _STRS, "entityId": _NULLABLE_STR, "entityType": _NULLABLE_STR}
    ),
    "RejectedNotification": _obj(
        (
            "id",
            "tenant",
            "receivedAt",
            "error",
            "description",
            "headers",
            "body",
            "bodyEncoding",
            "bodySize",
            "bodyTruncated",
        ),
        {
            "id": {"type": "integer"},
            "tenant": _STR,
            "receivedAt": _STR,
            "error": _STR,
            "description": _STR,
            "headers": {"type": "object", "additionalProperties": _STR, "description": "credentials redacted"},
            "body": _STR,
            "bodyEncoding": {"enum": ["utf-8", "base64"]},
            "bodySize": {"type": "integer"},
            "bodyTruncated": {"type": "boolean"},
        },
    ),
    # Grafana
    "InfinityRows": _array({"type": "object"}, "flat rows, one object each; columns named by attrs"),
    "SimpleJsonAnswer": {
        "anyOf": [
            _obj(("target", "datapoints"), {"target": _STR, "refId": _STR, "datapoints": _array(_array(_ANY))}),
            _obj(
                ("type", "columns", "rows"),
                {
                    "type": {"const": "table"},
                    "refId": _STR,
                    "columns": _array({"type": "object"}),
                    "rows": _array(_array(_ANY)),
                },
            ),
            _obj(("name", "fields"), {"name": _STR, "refId": _STR, "fields": _array(_FRAME_FIELD)}),
        ]
    },
    "Dashboard": {"type": "object", "description": "A Grafana dashboard (schemaVersion 42)"},
}


# --- responses -------------------------------------------------------------------------------------

_ERROR_TEXT = {
    400: "Bad request: a parameter, header or body is invalid",
    401: "No or invalid credential (only when API keys or tokens are configured)",
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
HISTORY_ERRORS = (400, *AUTH, 404, 409, 422, 503)


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
    return _array(ref(name))


def maybe_empty(name: str) -> dict:
    return {"anyOf": [ref(name), _EMPTY]}


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


_TENANT_SCHEMA = {"type": "string", "pattern": "^[A-Za-z0-9_]{0,50}$"}
# Service paths: /a/b; a query may list several (comma-separated, at most 50)
# and end one in /# for a subtree. Components are 1 to 256 characters, no
# whitespace or '#'. The patterns stay simple (the parser has the last word).
_SP_QUERY = {"type": "string", "pattern": r"^(/[^#\s,]*(/#)?|#)(,\s*/[^#\s,]*(/#)?)*$"}
_SP_NOTIFY = {"type": "string", "pattern": r"^/[^#\s,]*(,\s*/[^#\s,]*)*$"}

FIWARE_SERVICE = header("Fiware-Service", "Tenant (Orion lower-cases it); none is the default tenant.", _TENANT_SCHEMA)
NGSILD_TENANT = header(
    "NGSILD-Tenant", "NGSI-LD tenant; must agree with Fiware-Service when both are given.", _TENANT_SCHEMA
)
SERVICE_PATH_QUERY = header(
    "Fiware-ServicePath",
    "Service paths to read: comma list, /# for a subtree; none or / is the whole tenant.",
    _SP_QUERY,
)
TENANCY = [FIWARE_SERVICE, NGSILD_TENANT, SERVICE_PATH_QUERY]

_INT_MAX = 10**18 - 1  # history.params: at most 18 digits
_POSITIVE = {"type": "integer", "minimum": 1, "maximum": _INT_MAX}
_TIME = {"type": "string", "format": "date-time"}

ID = query("id", "Entity ids, comma-separated.")
TYPE = query("type", "Entity types, comma-separated.")
ID_PATTERN = query("idPattern", "Entity id regular expression (RE2 syntax, searched, linear time).")
ATTRS = query("attrs", "Attribute names or value paths (odom(twist.linear.x)), comma-separated.")
FROM_DATE = query("fromDate", "Oldest time index, inclusive (ISO 8601; naive means UTC).", _TIME)
TO_DATE = query("toDate", "Newest time index, inclusive (ISO 8601; naive means UTC).", _TIME)
LIMIT = query("limit", "At most this many rows (capped by the server's default limit).", _POSITIVE)
OFFSET = query("offset", "Rows to skip.", {"type": "integer", "minimum": 0, "maximum": _INT_MAX})
GEO = [
    query(
        "georel",
        "NGSIv2 geo relation: near;maxDistance:M;minDistance:M, coveredBy, intersects, equals, disjoint.",
        {"type": "string", "pattern": "^(near|coveredBy|intersects|equals|disjoint)(;.*)?$"},
    ),
    query("geometry", "Shape of coords.", {"enum": ["point", "line", "polygon", "box"]}),
    query("coords", "lat,lon pairs separated by ';'."),
]

HISTORY = [
    *TENANCY,
    ATTRS,
    FROM_DATE,
    TO_DATE,
    query("lastN", "Only the newest N samples per entity.", _POSITIVE),
    LIMIT,
    OFFSET,
    query("aggrMethod", "Aggregate per entity (case-insensitive).", {"enum": ["count", "sum", "avg", "min", "max"]}),
    query(
        "aggrPeriod",
        "Aggregation bucket; needs aggrMethod.",
        {"enum": ["year", "month", "day", "hour", "minute", "second"]},
    ),
    query(
        "aggrScope",
        "entity: one aggregate per entity; global: one across every matched entity.",
        {"enum": ["entity", "global"]},
    ),
    query("options", "QuantumLeap's options: not supported, any value is refused with 400."),
    *GEO,
]
ENTITY_HISTORY = [TYPE, *HISTORY]  # /v2/entities/{id}...: type disambiguates the id
TYPE_HISTORY = [ID, ID_PATTERN, *HISTORY]
ANY_HISTORY = [ID, TYPE, ID_PATTERN, *HISTORY]
ENTITY_LIST = [*TENANCY, ID, TYPE, ID_PATTERN, FROM_DATE, TO_DATE, LIMIT, OFFSET, *GEO]
DELETE = [
    *TENANCY,
    FROM_DATE,
    TO_DATE,
    query(
        "dropTable",
        "Accepted for QuantumLeap compatibility (true or false); history is deleted either way.",
        {"enum": ["true", "false"]},
    ),
]
DELETE_ENTITY = [TYPE, *DELETE]
EXPORT = [
    *TENANCY,
    ID,
    TYPE,
    ID_PATTERN,
    FROM_DATE,
    TO_DATE,
    query("attrs", "Attribute names (not value paths), comma-separated."),
    query("format", "File format.", {"enum": ["csv", "parquet"], "default": "csv"}),
]

NOTIFY_HEADERS = [
    header("Fiware-Service", "Tenant of the entities (letters, digits, _; up to 50).", _TENANT_SCHEMA),
    header("Fiware-ServicePath", "Service path of the entities: one, or one per entity (comma-separated).", _SP_NOTIFY),
    header("NGSILD-Tenant", "NGSI-LD tenant (Orion-LD); must agree with Fiware-Service.", _TENANT_SCHEMA),
    header(
        "Ngsiv2-AttrsFormat",
        "Orion's notification format; without it the body's shape decides.",
        {"enum": ["normalized", "keyValues", "values", "simplifiedNormalized", "simplifiedKeyValues", "legacy"]},
    ),
    header(
        "Ngsild-Attribute-Format",
        "Orion-LD's attribute format.",
        {"enum": ["Normalized", "Concise", "Simplified", "KeyValues"]},
    ),
    header(
        "Fiware-TimeIndex-Attribute",
        "Attribute (or metadata) whose value is the time index.",
        {"type": "string", "maxLength": 256},
    ),
]

_GRAFANA_TENANCY = [
    FIWARE_SERVICE,
    NGSILD_TENANT,
    SERVICE_PATH_QUERY,
    query(
        "service", "Tenant, for datasources that cannot send headers; must agree with Fiware-Service.", _TENANT_SCHEMA
    ),
    query("servicepath", "Service paths, as the Fiware-ServicePath header.", _SP_QUERY),
]
_GRAFANA_ENTITIES = [
    query("id", "Entity ids, comma-separated (at most 1000)."),
    query("idPattern", "Entity id regular expression (RE2 syntax)."),
    query("type", "Entity types, comma-separated (at most 100)."),
]
_GRAFANA_TIME = [
    query("from", "Start: epoch milliseconds (Grafana's ${__from}) or ISO 8601."),
    query("to", "End: epoch milliseconds or ISO 8601."),
]
_COLUMNS = "Columns: attribute names or value paths, each optionally alias=path, comma-separated (at most 64)."
_POINTS = {"type": "number", "minimum": 1}


def grafana_params(*extra: dict, attrs: bool | None = True, time: bool = True) -> list[dict]:
    """The Infinity endpoints' parameters: tenancy, entities, ``attrs``
    (required, optional or absent), the time range, then ``extra``."""
    params = [*_GRAFANA_TENANCY, *_GRAFANA_ENTITIES]
    if attrs is not None:
        params.append(query("attrs", _COLUMNS, required=attrs))
    if time:
        params += _GRAFANA_TIME
    return params + list(extra)


MAX_POINTS = query("max_points", "Samples per entity before downsampling (capped at 100000).", _POINTS)
GRAFANA_LIMIT = query("limit", "At most this many rows (capped at 100000).", _POINTS)

SUBSCRIBE = [
    FIWARE_SERVICE,
    SERVICE_PATH_QUERY,
    query(
        "orionUrl",
        "The broker's API base, e.g. http://orion:1026/v2.",
        {"type": "string", "format": "uri"},
        required=True,
    ),
    query(
        "quantumleapUrl",
        "Where the broker reaches this service, e.g. http://tsdb:8668/v2 (it notifies {quantumleapUrl}/notify).",
        {"type": "string", "format": "uri"},
        required=True,
    ),
    query("entityType", "Entity type to follow.", {"type": "string", "maxLength": 256}),
    query("entityId", "Entity id to follow (else idPattern).", {"type": "string", "maxLength": 256}),
    query("idPattern", "Entity id pattern to follow (default .*).", {"type": "string", "maxLength": 256}),
    query("attributes", "Attributes observed and notified, comma-separated."),
    query("observedAttributes", "Attributes whose change notifies, comma-separated."),
    query("notifiedAttributes", "Attributes notified, comma-separated."),
    query(
        "timeIndexAttribute",
        "Attribute carrying the time index (sent as Fiware-TimeIndex-Attribute).",
        {"type": "string", "maxLength": 256},
    ),
    query(
        "throttling",
        "Minimum seconds between notifications (default 1).",
        {"type": "integer", "minimum": 0, "maximum": 999_999_999},
    ),
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


LD_WRITE_ERRORS = (400, *AUTH, 404, 409, 413, 415, 503)
LD_HEADERS = (
    header("NGSILD-Tenant", "The tenant (as Fiware-Service; both must agree when given)", _TENANT_SCHEMA),
    header(
        "Link",
        'The JSON-LD @context of the body\'s terms, as a Link header (rel="http://www.w3.org/ns/json-ld#context")',
    ),
)


def ld_spec(
    *parameters: dict, ok_codes: dict[int, str], errors_: tuple[int, ...] = LD_WRITE_ERRORS, body: dict | None = None
) -> dict:
    """``spec`` for NGSI-LD routes: answers without a body on success, errors
    as ProblemDetails, the tenant and context headers declared."""
    extra: dict[str, Any] = {"parameters": [*LD_HEADERS, *parameters]}
    if body:
        extra.update(body)
    responses = {code: {"description": text} for code, text in ok_codes.items()}
    return {"response_model": None, "responses": {**responses, **ld_errors(*errors_)}, "openapi_extra": extra}


LD_READ_ERRORS = (400, *AUTH, 404, 406, 413, 415, 422, 503)
_LD_DOCUMENT = {
    "description": "Temporal entities (JSON, or JSON-LD with the @context in the body)",
    "content": {
        "application/json": {"schema": {"type": ["object", "array"]}},
        "application/ld+json": {"schema": {"type": ["object", "array"]}},
    },
}


def ld_read_spec(*, body: dict | None = None) -> dict:
    """``spec`` for the NGSI-LD temporal reads: a JSON or JSON-LD document,
    206 past the instance cap, errors as ProblemDetails."""
    extra: dict[str, Any] = {"parameters": list(LD_HEADERS)}
    if body:
        extra.update(body)
    partial = {**_LD_DOCUMENT, "description": "Partial: more instances than the cap (see Content-Range)"}
    return {
        "response_model": None,
        "openapi_extra": extra,
        "responses": {200: _LD_DOCUMENT, 206: partial, **ld_errors(*LD_READ_ERRORS)},
    }


LD_ENTITY_BODY = json_body(ref("EntityLD"), media_types=("application/json", "application/ld+json"))
LD_FRAGMENT_BODY = json_body({"type": "object"}, media_types=("application/json", "application/ld+json"))


# --- the whole document ----------------------------------------------------------------------------

OPEN = ("/health", "/version")  # security.guard.OPEN_PATHS: never need a credential


def security_schemes(api_key_header: str) -> dict:
    return {
        "ApiKeyHeader": {
            "type": "apiKey",
            "in": "header",
            "name": api_key_header,
            "description": "An API key (TSDB_API_KEYS), when keys are configured.",
        },
        "Bearer": {
            "type": "http",
            "scheme": "bearer",
            "bearerFormat": "API key or JWT",
            "description": "An API key, or an OAuth2 JWT (Keyrock, Keycloak) when TSDB_JWT_* is set.",
        },
    }


def complete(doc: dict, api_key_header: str) -> dict:
    """Add the shared components and the optional security; drop FastAPI's
    422 validation answer, which this service never sends."""
    components = doc.setdefault("components", {})
    schemas = components.setdefault("schemas", {})
    for name in ("HTTPValidationError", "ValidationError"):
        schemas.pop(name, None)
    schemas.update(SCHEMAS)
    components["securitySchemes"] = security_schemes(api_key_header)
    # Optional: {} means "no credential", which is the default configuration.
    doc["security"] = [{}, {"ApiKeyHeader": []}, {"Bearer": []}]
    for path, item in doc.get("paths", {}).items():
        for operation in item.values():
            responses = operation.get("responses", {})
            if _is_validation_error(responses.get("422")):
                del responses["422"]
            for response in responses.values():
                _drop_placeholder(response.get("content"))
            if path in OPEN:
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


def install(app, api_key_header: str = "X-Api-Key") -> None:
    """Make ``app.openapi()`` return the completed document (built once)."""
    generate = app.openapi
    done: list[dict] = []

    def openapi() -> dict:
        if not done:
            done.append(complete(generate(), api_key_header))
        return done[0]

    app.openapi = openapi


# --- per-route declarations -------------------------------------------------------------------------

_NOTIFY_EXAMPLES = {
    "ngsiv2": {
        "subscriptionId": "5f1a",
        "data": [
            {
                "id": "urn:ngsi-ld:Room:1",
                "type": "Room",
                "temperature": {"type": "Number", "value": 21.5},
                "TimeInstant": {"type": "DateTime", "value": "2024-05-01T10:00:00Z"},
            }
        ],
    },
    "ngsi-ld": {
        "id": "urn:ngsi-ld:Notification:1",
        "type": "Notification",
        "subscriptionId": "urn:sub:1",
        "notifiedAt": "2024-05-01T10:00:00Z",
        "data": [
            {
                "id": "urn:ngsi-ld:Room:2",
                "type": "Room",
                "temperature": {"type": "Property", "value": 19, "observedAt": "2024-05-01T10:00:00Z"},
            }
        ],
    },
}
NOTIFY = spec(
    *NOTIFY_HEADERS,
    ok_=ok({"const": "Notification successfully processed"}, "Stored (committed) before this answer"),
    errors_=(400, *AUTH, 413, 415, 503),
    body=json_body(
        ref("Notification"),
        media_types=("application/json", "application/ld+json", "application/geo+json"),
        examples=_NOTIFY_EXAMPLES,
    ),
)

_NEXT = {
    "Link": {
        "description": 'The next page: <...>; rel="next" (only when more rows follow)',
        "schema": {"type": "string"},
    },
    "X-Next-Offset": {"description": "offset of the next page", "schema": {"type": "integer"}},
}
HINT = {
    "X-Tsdb-Hint": {
        "description": "On an empty answer whose tenant holds no data: the tenants that do "
        "(the body stays QuantumLeap's [])",
        "schema": {"type": "string"},
    }
}


def with_headers(operation: dict, headers: dict, status: int = 200) -> dict:
    """``operation`` (a ``spec``) with ``headers`` declared on its ``status`` answer."""
    operation["responses"][status]["headers"] = headers
    return operation


REJECTED = with_headers(
    spec(FIWARE_SERVICE, NGSILD_TENANT, ok_=ok(ref_array("RejectedNotification")), errors_=(400, *AUTH, 503)), _NEXT
)

LAYOUTS = {"type": "object", "additionalProperties": ref("ValuesLayout"), "description": "subscription id → layout"}
PUT_LAYOUT = spec(
    FIWARE_SERVICE,
    NGSILD_TENANT,
    ok_=ok(ref("ValuesLayout"), "Registered"),
    errors_=(400, *AUTH, 503),
    body=json_body(
        {
            "anyOf": [
                _obj(("attrs",), {"attrs": {**_STRS, "minItems": 1}, "entityId": _STR, "entityType": _STR}, extra=True),
                _obj(
                    ("notification",),
                    {"notification": {"type": "object"}, "subject": {"type": "object"}},
                    extra=True,
                    description="A whole Orion subscription: notification.attrs and subject.entities are used",
                ),
            ]
        },
        examples={"short": {"attrs": ["id", "type", "temperature"]}},
    ),
)

OP_QUERY = spec(
    FIWARE_SERVICE,
    NGSILD_TENANT,
    SERVICE_PATH_QUERY,
    ok_=ok(ref_array("LastValueEntity")),
    errors_=READ_ERRORS,
    body=json_body(
        _obj(
            ("entities",),
            {
                "entities": {
                    **_array(
                        {
                            **_obj((), {"id": _STR, "idPattern": _STR, "type": _STR}, extra=True),
                            "oneOf": [{"required": ["id"]}, {"required": ["idPattern"]}],
                        }
                    ),
                    "minItems": 1,
                },
                "attrs": _array({"type": "string", "minLength": 1}, "attribute names or value paths"),
            },
            extra=True,
            description="Orion's query form; 'expression' and 'metadata' are refused (NotSupported)",
        ),
        examples={"one": {"entities": [{"id": "urn:ngsi-ld:Room:1", "type": "Room"}]}},
    ),
)

SUBSCRIBED = _obj(
    ("subscriptionId", "location", "subscription"),
    {"subscriptionId": _NULLABLE_STR, "location": _NULLABLE_STR, "subscription": {"type": "object"}},
)

EXPORT_SPEC = spec(
    *EXPORT,
    ok_={
        200: {
            "description": "One row per sample, streamed",
            "content": {
                "text/csv": {"schema": {"type": "string"}},
                "application/vnd.apache.parquet": {"schema": {"type": "string", "format": "binary"}},
            },
        }
    },
    errors_=READ_ERRORS,
)

VERSION = _obj(("version",), {"version": _STR})
HEALTH = spec(
    ok_={
        200: {"description": "Healthy", "content": {"application/health+json": {"schema": ref("Health")}}},
        503: {
            "description": "Failing: restart or fix the store",
            "content": {"application/health+json": {"schema": ref("Health")}},
        },
    },
    errors_=(),
)
SCHEMAS["Health"] = _obj(("status",), {"status": {"enum": ["pass", "warn", "fail"]}, "output": _STR})
API_INDEX = {"type": "object", "additionalProperties": _STR}
METRICS = spec(ok_=ok({"type": "string"}, "Prometheus text exposition format", "text/plain"), errors_=AUTH)

SUBSCRIBE_SPEC = spec(*SUBSCRIBE, ok_=ok(SUBSCRIBED, "Created at the broker", status=201), errors_=(400, *AUTH, 502))
SUBSCRIBE_SPEC["responses"]["4XX"] = {
    "description": "The broker's own 4xx, passed on",
    "content": {"application/json": {"schema": ref("NgsiError")}},
}


# --- Grafana ---------------------------------------------------------------------------------------

_GRAFANA_ERRORS = READ_ERRORS


def _rows(*required: str) -> dict:
    """Infinity's flat rows: the named keys always, a key per column besides."""
    return _array({"type": "object", "required": list(required)}) if required else ref("InfinityRows")


def _infinity(rows: dict, *parameters: dict, attrs: bool | None = True, time: bool = True) -> dict:
    return spec(*grafana_params(*parameters, attrs=attrs, time=time), ok_=ok(rows), errors_=_GRAFANA_ERRORS)


_AGG = ["auto", "avg", "last", "first", "min", "max", "sum", "count"]  # grafana.frames.AGGREGATIONS
INFINITY = {
    "series": _infinity(
        _rows("time"),
        MAX_POINTS,
        query("interval_ms", "Minimum bucket width in milliseconds.", {"type": "number", "minimum": 1}),
        query("agg", "Downsampling: auto (avg for numbers, last for states) or a fixed reducer.", {"enum": _AGG}),
        query("layout", "long: a row per entity and time; wide: a row per time.", {"enum": ["long", "wide"]}),
    ),
    "latest": _infinity(_rows("entity", "type", "name"), time=False),
    "states": _infinity(_rows("time", "entity"), MAX_POINTS),
    "events": _infinity(
        _rows("time", "timeEnd", "entity", "title", "text", "tags"),
        query("equals", "A JSON value: an event is a run of samples equal to it (default: truthy)."),
        query("text", "Event text."),
        GRAFANA_LIMIT,
    ),
    "positions": _infinity(
        _rows("time", "entity", "type", "name", "lat", "lon"),
        query("location", "Attribute or value path holding the position (default location)."),
        query(
            "latest",
            "Only each entity's latest position.",
            {"enum": ["true", "false", "1", "0", "yes", "no", "on", "off"]},
        ),
        MAX_POINTS,
        *GEO,
        attrs=False,
    ),
    "aggregate": _infinity(
        _rows("entity", "type", "name"),
        query("method", "Aggregate.", {"enum": ["avg", "min", "max", "sum", "count"]}),
        query(
            "period",
            "One aggregate per period instead of per entity.",
            {"enum": ["", "second", "minute", "hour", "day", "month", "year"]},
        ),
        GRAFANA_LIMIT,
    ),
    "entities": _infinity(_rows("entity", "type", "name", "attrs"), attrs=None, time=False),
}

_SJ_TENANCY = _GRAFANA_TENANCY
_OPEN_BODY = {"type": "object", "description": "Grafana's request; unknown members are ignored"}


def _simplejson(answer: dict, body: dict | None = None, example: dict | None = None) -> dict:
    schema = {**_OPEN_BODY, **(body or {})}
    return spec(
        *_SJ_TENANCY,
        ok_=ok(answer),
        errors_=_GRAFANA_ERRORS,
        body=json_body(schema, required=False, examples={"example": example} if example else None),
    )


_LABEL_VALUE = _obj(("label", "value"), {"label": _STR, "value": _STR})
_RANGE = {
    "type": "object",
    "properties": {"from": {"type": ["string", "number"]}, "to": {"type": ["string", "number"]}},
}
_TARGET = {
    "type": "object",
    "properties": {
        "target": {"type": "string", "description": "<entity id or *>/<attribute or value path>"},
        "refId": _STR,
        "type": _STR,
        "hide": {"type": "boolean"},
        "payload": {
            "type": "object",
            "properties": {
                "path": _STR,
                "type": _STR,
                "idPattern": _STR,
                "alias": _STR,
                "agg": {"enum": _AGG},
                "format": {"enum": ["timeseries", "table", "dataframe", "annotations"]},
                "equals": _ANY,
            },
        },
    },
}
SIMPLEJSON = {
    "test": spec(
        *_SJ_TENANCY,
        ok_=ok(
            _obj(
                ("status", "tenant", "servicePaths"), {"status": {"const": "ok"}, "tenant": _STR, "servicePaths": _STRS}
            )
        ),
        errors_=_GRAFANA_ERRORS,
    ),
    "search": _simplejson(_STRS, {"properties": {"target": _STR}}, {"target": ""}),
    "variable": _simplejson(
        _array(_obj(("__text", "__value"), {"__text": _STR, "__value": _STR})),
        {"properties": {"payload": {"anyOf": [_STR, {"type": "object", "properties": {"target": _STR}}]}}},
        {"payload": {"target": "entities"}},
    ),
    "metrics": _simplejson(
        _array(
            _obj(("label", "value", "payloads"), {"label": _STR, "value": _STR, "payloads": _array({"type": "object"})})
        ),
        {"properties": {"metric": _STR}},
    ),
    "metric-payload-options": _simplejson(
        _array(_LABEL_VALUE),
        {"properties": {"metric": _STR, "name": _STR, "payload": {"type": "object"}}},
        {"metric": "*/location", "name": "path"},
    ),
    "query": _simplejson(
        _array(ref("SimpleJsonAnswer")),
        {
            "properties": {
                "range": _RANGE,
                "intervalMs": {"type": "number"},
                "maxDataPoints": {"type": "number"},
                "targets": {**_array(_TARGET), "maxItems": 50},
                "adhocFilters": _array({"type": "object"}),
            }
        },
        {
            "range": {"from": "2024-05-01T00:00:00Z", "to": "2024-05-02T00:00:00Z"},
            "targets": [{"target": "*/temperature", "refId": "A"}],
        },
    ),
    "annotations": _simplejson(
        _array({"type": "object", "required": ["annotation", "time", "timeEnd", "isRegion", "title", "text", "tags"]}),
        {"properties": {"range": _RANGE, "annotation": {"type": "object", "properties": {"query": _STR}}}},
    ),
    "tag-keys": _simplejson(_array(_obj(("type", "text"), {"type": _STR, "text": _STR}))),
    "tag-values": _simplejson(_array(_obj(("text",), {"text": _STR})), {"properties": {"key": _STR}}),
}

_NULLABLE_STR = {"type": ["string", "null"]}
DASHBOARDS = spec(
    ok_=ok(
        _array(
            _obj(
                ("name", "use_case", "uid", "title", "tags", "url", "datasource_uid", "datasources"),
                {
                    "name": _STR,
                    "use_case": _NULLABLE_STR,
                    "uid": _STR,
                    "title": _STR,
                    "tags": _STRS,
                    "url": _STR,
                    "datasource_uid": _NULLABLE_STR,
                    "datasources": _array(_obj(("type", "uid"), {"type": _NULLABLE_STR, "uid": _STR})),
                },
            )
        )
    ),
    errors_=AUTH,
)
DASHBOARD = spec(ok_=ok(ref("Dashboard")), errors_=(*AUTH, 404))

# --- the explorer ------------------------------------------------------------------------------------

UI_PAGE = spec(ok_=ok({"type": "string"}, "The explorer page", "text/html"), errors_=AUTH)
UI_TENANTS = spec(
    ok_=ok(
        _array(
            _obj(
                ("tenant", "servicePaths", "types", "entities", "series"),
                {
                    "tenant": _STR,
                    "servicePaths": _STRS,
                    "types": _STRS,
                    "entities": {"type": "integer"},
                    "series": {"type": "integer"},
                },
            )
        )
    ),
    errors_=(*AUTH, 503),
)
UI_USECASES = spec(ok_=ok({"type": "object", "additionalProperties": {"type": "object"}}), errors_=AUTH)
