"""``/v2/attrs``: attribute histories across entities and types."""

from __future__ import annotations

from fastapi import APIRouter, Request

from tsdb_service.core.query import Shape
from tsdb_service.faces.quantumleap import openapi as ql_oa
from tsdb_service.faces.quantumleap.history import answer_history_async
from tsdb_service.http import openapi as oa
from tsdb_service.http.responses import JSON

router = APIRouter(tags=["attrs"])


@router.get(
    "/v2/attrs",
    summary="History of N attributes of every entity",
    **oa.spec(*ql_oa.ANY_HISTORY, ok_=oa.ok(ql_oa.maybe_empty("AttrsHistory")), errors_=ql_oa.HISTORY_ERRORS),
)
async def attrs(request: Request) -> JSON:
    return await answer_history_async(request, Shape.ATTRS)


@router.get(
    "/v2/attrs/value",
    summary="History of N attributes of every entity (values only)",
    **oa.spec(*ql_oa.ANY_HISTORY, ok_=oa.ok(ql_oa.maybe_empty("AttrsValues")), errors_=ql_oa.HISTORY_ERRORS),
)
async def attrs_value(request: Request) -> JSON:
    return await answer_history_async(request, Shape.ATTRS, values_only=True)


@router.get(
    "/v2/attrs/{attr_name}",
    summary="History of one attribute of every entity",
    **oa.spec(*ql_oa.ANY_HISTORY, ok_=oa.ok(ql_oa.maybe_empty("AttrHistory")), errors_=ql_oa.HISTORY_ERRORS),
)
async def attr(attr_name: str, request: Request) -> JSON:
    return await answer_history_async(request, Shape.ATTR, attr=attr_name)


@router.get(
    "/v2/attrs/{attr_name}/value",
    summary="History of one attribute of every entity (values only)",
    **oa.spec(*ql_oa.ANY_HISTORY, ok_=oa.ok(ql_oa.maybe_empty("AttrValues")), errors_=ql_oa.HISTORY_ERRORS),
)
async def attr_value(attr_name: str, request: Request) -> JSON:
    return await answer_history_async(request, Shape.ATTR, attr=attr_name, values_only=True)
