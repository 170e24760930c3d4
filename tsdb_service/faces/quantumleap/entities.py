"""``GET /v2/entities``: the entity ids with their type and latest time index."""

from __future__ import annotations

from fastapi import APIRouter, Request

from tsdb_service.faces.quantumleap import openapi as ql_oa
from tsdb_service.faces.quantumleap.paging import limit_headers
from tsdb_service.faces.quantumleap.params import entity_list_query
from tsdb_service.history.service import run_entity_list
from tsdb_service.http import openapi as oa
from tsdb_service.http.responses import JSON
from tsdb_service.http.store import reads_store, store_of
from tsdb_service.http.tenancy import empty_answer_hint, tenant_of

router = APIRouter(tags=["entities"])


@router.get(
    "/v2/entities",
    summary="Entity ids with their type and latest time index",
    **oa.with_headers(
        oa.spec(*ql_oa.ENTITY_LIST, ok_=oa.ok(oa.ref_array("EntityListItem")), errors_=oa.READ_ERRORS), ql_oa.HINT
    ),
)
@reads_store
def list_entities(request: Request) -> JSON:
    query = entity_list_query(
        request.query_params, request.headers, tenant_of(request), request.app.state.settings.default_limit
    )
    found = run_entity_list(store_of(request).querier(), query)
    if not found:
        return JSON(found, headers=empty_answer_hint(request, query.scope.tenant))
    return JSON(found, headers=limit_headers(request, query.limit, query.offset, [len(found)]) or None)
