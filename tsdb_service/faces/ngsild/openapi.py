"""The NGSI-LD temporal API's part of the OpenAPI description: ProblemDetails answers, tenant and context headers."""

from __future__ import annotations

from typing import Any

from tsdb_service.http.openapi import AUTH, TENANT_SCHEMA, header, json_body, ld_errors, ref

LD_WRITE_ERRORS = (400, *AUTH, 404, 409, 413, 415, 503)


LD_HEADERS = (
    header("NGSILD-Tenant", "The tenant (as Fiware-Service; both must agree when given)", TENANT_SCHEMA),
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
