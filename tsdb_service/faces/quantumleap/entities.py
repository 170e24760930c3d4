"""``/v2/entities``: the entity list, one entity's history, and its deletion."""

from __future__ import annotations

from functools import partial

from fastapi import APIRouter, Request
from starlette.responses import Response

from tsdb_service.core.query import Shape
from tsdb_service.faces.quantumleap import openapi as ql_oa
from tsdb_service.faces.quantumleap.history import answer_history_async
from tsdb_service.faces.quantumleap.params import delete_query, entity_list_query
from tsdb_service.history.service import delete_target, run_entity_list
from tsdb_service.http import openapi as oa
from tsdb_service.http.responses import JSON
from tsdb_service.http.store import reads_store, store_of
from tsdb_service.http.tenancy import tenant_of
from tsdb_service.write.ops import DeleteSamples

router = APIRouter(tags=["entities"])


@router.get(
    "/v2/entities",
    summary="Entity ids with their type and latest time index",
    **oa.spec(*ql_oa.ENTITY_LIST, ok_=oa.ok(oa.ref_array("EntityListItem")), errors_=oa.READ_ERRORS),
)
@reads_store
def list_entities(request: Request) -> JSON:
    query = entity_list_query(
        request.query_params, request.headers, tenant_of(request), request.app.state.settings.default_limit
    )
    return JSON(run_entity_list(store_of(request).querier(), query))


@router.get(
    "/v2/entities/{entity_id}",
    summary="History of N attributes of one entity",
    **oa.spec(*ql_oa.ENTITY_HISTORY, ok_=oa.ok(ql_oa.maybe_empty("EntityHistory")), errors_=ql_oa.HISTORY_ERRORS),
)
async def entity(entity_id: str, request: Request) -> JSON:
    return await answer_history_async(request, Shape.ENTITY, entity_id=entity_id)


@router.get(
    "/v2/entities/{entity_id}/value",
    summary="History of N attributes of one entity (values only)",
    **oa.spec(*ql_oa.ENTITY_HISTORY, ok_=oa.ok(ql_oa.maybe_empty("EntityValues")), errors_=ql_oa.HISTORY_ERRORS),
)
async def entity_value(entity_id: str, request: Request) -> JSON:
    return await answer_history_async(request, Shape.ENTITY, entity_id=entity_id, values_only=True)


@router.get(
    "/v2/entities/{entity_id}/attrs/{attr_name}",
    summary="History of one attribute of one entity",
    **oa.spec(*ql_oa.ENTITY_HISTORY, ok_=oa.ok(ql_oa.maybe_empty("EntityAttrHistory")), errors_=ql_oa.HISTORY_ERRORS),
)
async def entity_attr(entity_id: str, attr_name: str, request: Request) -> JSON:
    return await answer_history_async(request, Shape.ENTITY_ATTR, entity_id=entity_id, attr=attr_name)


@router.get(
    "/v2/entities/{entity_id}/attrs/{attr_name}/value",
    summary="History of one attribute of one entity (values only)",
    **oa.spec(*ql_oa.ENTITY_HISTORY, ok_=oa.ok(ql_oa.maybe_empty("EntityAttrValues")), errors_=ql_oa.HISTORY_ERRORS),
)
async def entity_attr_value(entity_id: str, attr_name: str, request: Request) -> JSON:
    return await answer_history_async(request, Shape.ENTITY_ATTR, entity_id=entity_id, attr=attr_name, values_only=True)


@router.delete(
    "/v2/entities/{entity_id}",
    status_code=204,
    summary="Delete the history of one entity",
    **oa.spec(*ql_oa.DELETE_ENTITY, ok_={204: {"description": "Deleted"}}, errors_=(400, *oa.AUTH, 404, 409, 503)),
)
async def delete_entity(entity_id: str, request: Request) -> Response:
    query = delete_query(request.query_params, request.headers, tenant_of(request), entity_id=entity_id)
    store = store_of(request)
    sids, time = await store.read(partial(delete_target, store.querier(), query), memory_first=False)
    await store.write(DeleteSamples(tuple(sids), time.start, time.end))
    return Response(status_code=204)
