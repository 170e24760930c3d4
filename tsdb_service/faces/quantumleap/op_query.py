"""``POST /v2/op/query``: the last value of each entity, in NGSIv2 entity form.

The body is Orion's query form: ``{"entities": [{"id" | "idPattern",
"type"?}], "attrs": [...]}``. Each entity comes back as ``{"id", "type",
attr: {"type", "value"}, ..., "dateModified": {"type": "DateTime", "value"}}``,
with every attribute at its latest stored value.

``?asOf=`` (our extension; QuantumLeap has no such read) answers the same
entities as they were at that instant: each attribute at its latest value
at or before it, with the time of that value as its ``dateModified``
metadata; entities with no value by then are left out. Reconstructing a
fleet at the moment of an incident is one request.
"""

from __future__ import annotations

from dataclasses import replace
from functools import partial

import orjson
from fastapi import APIRouter, Request

from tsdb_service.core.errors import BadRequest, ParseError
from tsdb_service.core.query import EntityFilter, LastValueQuery, Scope
from tsdb_service.faces.quantumleap import openapi as ql_oa
from tsdb_service.history.service import run_last_values
from tsdb_service.history.valuepath import parse_value_path
from tsdb_service.http.responses import JSON
from tsdb_service.http.store import store_of
from tsdb_service.http.tenancy import tenant_of
from tsdb_service.parse.request_context import MAX_IDS, check_id, id_pattern, parse_time, service_paths

router = APIRouter(tags=["op"])


@router.post(
    "/v2/op/query",
    summary="Last value of each matching entity (QuantumLeap as context provider)",
    **ql_oa.OP_QUERY,
)
async def op_query(request: Request) -> JSON:
    body = await request.body()  # at most TSDB_MAX_REQUEST_BODY_BYTES (http.bodies)
    query = last_value_query(body, tenant_of(request), request.headers.get("fiware-servicepath"))
    as_of = request.query_params.get("asOf")
    if as_of not in (None, ""):
        query = replace(query, as_of=parse_time(as_of, "asOf"))
    store = store_of(request)
    entities = await store.read(partial(run_last_values, store.querier(), query), memory_first=False)
    return JSON(entities)


def last_value_query(body: bytes, tenant: str, service_path: str | None) -> LastValueQuery:
    """The body, checked by the request-context rules every API shares
    (``parse.request_context``: ids, types, idPattern, service paths)."""
    try:
        doc = orjson.loads(body)
    except orjson.JSONDecodeError as exc:
        raise ParseError(f"query body is not valid JSON: {exc}") from None
    if not isinstance(doc, dict):
        raise BadRequest("query body must be a JSON object with 'entities'")
    for unsupported in ("expression", "metadata"):
        if unsupported in doc:
            raise BadRequest(f"{unsupported} is Not Supported", error="NotSupported")
    entities = doc.get("entities")
    if not isinstance(entities, list) or not entities:
        raise BadRequest('\'entities\' must be a non-empty array of {"id" or "idPattern", "type"}')
    if len(entities) > MAX_IDS:
        raise BadRequest(f"'entities' lists at most {MAX_IDS} entities")
    selectors = []
    for i, item in enumerate(entities):
        if not isinstance(item, dict):
            raise BadRequest(f"entities[{i}] must be an object")
        eid, pattern, etype = item.get("id"), item.get("idPattern"), item.get("type")
        if (eid is None) == (pattern is None):
            raise BadRequest(f"entities[{i}] needs exactly one of 'id' and 'idPattern'")
        for name, value in (("id", eid), ("idPattern", pattern), ("type", etype)):
            if value is not None and (not isinstance(value, str) or not value or len(value) > 1024):
                raise BadRequest(f"entities[{i}].{name} must be a non-empty string")
            if value is not None and name != "idPattern":
                check_id(value, f"entities[{i}].{name}")  # the ingest's rule for ids and types
        id_pattern(pattern, f"entities[{i}].idPattern")
        selectors.append(
            EntityFilter(
                ids=(eid,) if eid is not None else None,
                id_pattern=pattern,
                types=(etype,) if etype is not None else None,
            )
        )
    attrs = doc.get("attrs")
    paths = None
    if attrs is not None:
        if not isinstance(attrs, list) or not all(isinstance(a, str) and a for a in attrs):
            raise BadRequest("'attrs' must be an array of attribute names")
        if attrs:
            paths = tuple(dict.fromkeys(parse_value_path(a) for a in attrs))
    return LastValueQuery(Scope(tenant, service_paths(service_path)), tuple(selectors), paths)
