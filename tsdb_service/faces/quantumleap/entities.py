"""``/v2/entities``: the entity list, one entity's history, and its deletion."""

from __future__ import annotations

from functools import partial

from fastapi import APIRouter, Request
from starlette.responses import Response

from tsdb_service.core.query import Shape
from tsdb_service.faces.quantumleap.history import answer_history_async
from tsdb_service.faces.quantumleap.params import delete_query, entity_list_query
from tsdb_service.history.service import delete_target, run_entity_list
from tsdb_service.http import openapi as oa
from tsdb_service.http.responses import JSON
from tsdb_service.http.store import reads_store
from tsdb_service.http.tenancy import empty_answer_hint, tenant_of
from tsdb_service.storage.base import DeleteSamples

router = APIRouter(tags=["entities"])


@router.get(
    "/v2/entities",
    summary="Entity ids with their type and latest time index",
    **oa.with_headers(
        oa.spec(*oa.ENTITY_LIST, ok_=oa.ok(oa.ref_array("EntityListItem")), errors_=oa.READ_ERRORS), oa.HINT
    ),
)
@reads_store
def list_entities(request: Request) -> JSON:
    query = entity_list_query(
        request.query_params, request.headers, tenant_of(request), request.app.state.settings.default_limit
    )
    found = run_entity_list(request.app.state.store.querier(), query)
    return JSON(found, headers=None if found else empty_answer_hint(request, query.scope.tenant))


@router.get(
    "/v2/entities/{entity_id}",
    summary="History of N attributes of one entity",
    **oa.spec(*oa.ENTITY_HISTORY, ok_=oa.ok(oa.maybe_empty("EntityHistory")), errors_=oa.HISTORY_ERRORS),
)
async def entity(entity_id: str, request: Request) -> JSON:
    return await answer_history_async(request, Shape.ENTITY, entity_id=entity_id)


@router.get(
    "/v2/entities/{entity_id}/value",
    summary="History of N attributes of one entity (values only)",
    **oa.spec(*oa.ENTITY_HISTORY, ok_=oa.ok(oa.maybe_empty("EntityValues")), errors_=oa.HISTORY_ERRORS),
)
async def entity_value(entity_id: str, request: Request) -> JSON:
    return await answer_history_async(request, Shape.ENTITY, entity_id=entity_id, values_only=True)


@router.get(
    "/v2/entities/{entity_id}/attrs/{attr_name}",
    summary="History of one attribute of one entity",
    **oa.spec(*oa.ENTITY_HISTORY, ok_=oa.ok(oa.maybe_empty("EntityAttrHistory")), errors_=oa.HISTORY_ERRORS),
)
async def entity_attr(entity_id: str, attr_name: str, request: Request) -> JSON:
    return await answer_history_async(request, Shape.ENTITY_ATTR, entity_id=entity_id, attr=attr_name)


@router.get(
    "/v2/entities/{entity_id}/attrs/{attr_name}/value",
    summary="History of one attribute of one entity (values only)",
    **oa.spec(*oa.ENTITY_HISTORY, ok_=oa.ok(oa.maybe_empty("EntityAttrValues")), errors_=oa.HISTORY_ERRORS),
)
async def entity_attr_value(entity_id: str, attr_name: str, request: Request) -> JSON:
    return await answer_history_async(request, Shape.ENTITY_ATTR, entity_id=entity_id, attr=attr_name, values_only=True)


@router.delete(
    "/v2/entities/{entity_id}",
    status_code=204,
    summary="Delete the history of one entity",
    **oa.spec(*oa.DELETE_ENTITY, ok_={204: {"description": "Deleted"}}, errors_=(400, *oa.AUTH, 404, 409, 503)),
)
async def delete_entity(entity_id: str, request: Request) -> Response:
    query = delete_query(request.query_params, request.headers, tenant_of(request), entity_id=entity_id)
    store = request.app.state.store
    sids, time = await store.read(partial(delete_target, store.querier(), query), memory_first=False)
    await store.write(DeleteSamples(tuple(sids), time.start, time.end))
    return Response(status_code=204)
