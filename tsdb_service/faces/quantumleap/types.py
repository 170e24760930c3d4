"""``/v2/types/{entityType}``: the history of every entity of a type."""

from __future__ import annotations

from functools import partial

from fastapi import APIRouter, Request
from starlette.responses import Response

from tsdb_service.core.query import Shape
from tsdb_service.faces.quantumleap import openapi as ql_oa
from tsdb_service.faces.quantumleap.history import answer_history_async
from tsdb_service.faces.quantumleap.params import delete_query
from tsdb_service.history.service import delete_target
from tsdb_service.http import openapi as oa
from tsdb_service.http.responses import JSON
from tsdb_service.http.store import store_of
from tsdb_service.http.tenancy import tenant_of
from tsdb_service.write.ops import DeleteSamples

router = APIRouter(tags=["types"])


@router.get(
    "/v2/types/{entity_type}",
    summary="History of N attributes of the entities of a type",
    **oa.spec(*ql_oa.TYPE_HISTORY, ok_=oa.ok(ql_oa.maybe_empty("TypeHistory")), errors_=ql_oa.HISTORY_ERRORS),
)
async def entity_type(entity_type: str, request: Request) -> JSON:
    return await answer_history_async(request, Shape.TYPE, entity_type=entity_type)


@router.get(
    "/v2/types/{entity_type}/value",
    summary="History of N attributes of a type's entities (values only)",
    **oa.spec(*ql_oa.TYPE_HISTORY, ok_=oa.ok(ql_oa.maybe_empty("TypeValues")), errors_=ql_oa.HISTORY_ERRORS),
)
async def entity_type_value(entity_type: str, request: Request) -> JSON:
    return await answer_history_async(request, Shape.TYPE, entity_type=entity_type, values_only=True)


@router.get(
    "/v2/types/{entity_type}/attrs/{attr_name}",
    summary="History of one attribute of a type's entities",
    **oa.spec(*ql_oa.TYPE_HISTORY, ok_=oa.ok(ql_oa.maybe_empty("TypeAttrHistory")), errors_=ql_oa.HISTORY_ERRORS),
)
async def type_attr(entity_type: str, attr_name: str, request: Request) -> JSON:
    return await answer_history_async(request, Shape.TYPE_ATTR, entity_type=entity_type, attr=attr_name)


@router.get(
    "/v2/types/{entity_type}/attrs/{attr_name}/value",
    summary="History of one attribute of a type's entities (values only)",
    **oa.spec(*ql_oa.TYPE_HISTORY, ok_=oa.ok(ql_oa.maybe_empty("TypeAttrValues")), errors_=ql_oa.HISTORY_ERRORS),
)
async def type_attr_value(entity_type: str, attr_name: str, request: Request) -> JSON:
    return await answer_history_async(
        request, Shape.TYPE_ATTR, entity_type=entity_type, attr=attr_name, values_only=True
    )


@router.delete(
    "/v2/types/{entity_type}",
    status_code=204,
    summary="Delete the history of every entity of a type",
    **oa.spec(*ql_oa.DELETE, ok_={204: {"description": "Deleted"}}, errors_=(400, *oa.AUTH, 404, 503)),
)
async def delete_type(entity_type: str, request: Request) -> Response:
    query = delete_query(request.query_params, request.headers, tenant_of(request), entity_type=entity_type)
    store = store_of(request)
    sids, time = await store.read(partial(delete_target, store.querier(), query), memory_first=False)
    await store.write(DeleteSamples(tuple(sids), time.start, time.end))
    return Response(status_code=204)
