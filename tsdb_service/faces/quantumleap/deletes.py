"""``DELETE /v2/entities/{id}`` and ``DELETE /v2/types/{type}``: history removed.

Both resolve their series like the reads (404 when nothing matches; for an
entity id in several types, 409 unless ``type`` says which) and ask the
writer for one ``DeleteSamples``; samples written after the delete was
acknowledged are never touched.
"""

from __future__ import annotations

from functools import partial

from fastapi import APIRouter, Request
from starlette.responses import Response

from tsdb_service.faces.quantumleap import openapi as ql_oa
from tsdb_service.faces.quantumleap.params import delete_query
from tsdb_service.history.service import delete_target
from tsdb_service.http import openapi as oa
from tsdb_service.http.store import store_of
from tsdb_service.http.tenancy import tenant_of
from tsdb_service.write.ops import DeleteSamples

router = APIRouter()
_DELETED = {204: {"description": "Deleted"}}


async def _delete(request: Request, **target: str) -> Response:
    query = delete_query(request.query_params, request.headers, tenant_of(request), **target)
    store = store_of(request)
    sids, time = await store.read(partial(delete_target, store.querier(), query), memory_first=False)
    await store.write(DeleteSamples(tuple(sids), time.start, time.end))
    return Response(status_code=204)


@router.delete(
    "/v2/entities/{entity_id}",
    status_code=204,
    tags=["entities"],
    summary="Delete the history of one entity",
    **oa.spec(*ql_oa.DELETE_ENTITY, ok_=_DELETED, errors_=(400, *oa.AUTH, 404, 409, 503)),
)
async def delete_entity(entity_id: str, request: Request) -> Response:
    return await _delete(request, entity_id=entity_id)


@router.delete(
    "/v2/types/{entity_type}",
    status_code=204,
    tags=["types"],
    summary="Delete the history of every entity of a type",
    **oa.spec(*ql_oa.DELETE, ok_=_DELETED, errors_=(400, *oa.AUTH, 404, 503)),
)
async def delete_type(entity_type: str, request: Request) -> Response:
    return await _delete(request, entity_type=entity_type)
