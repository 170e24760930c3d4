"""``/v2/attrs``: attribute histories across entities and types."""

from __future__ import annotations

from fastapi import APIRouter, Request

from ..history.query import Shape
from .history import answer_history
from .responses import JSON

router = APIRouter(tags=["attrs"])


@router.get("/v2/attrs", summary="History of N attributes of every entity")
def attrs(request: Request) -> JSON:
    return answer_history(request, Shape.ATTRS)


@router.get("/v2/attrs/value", summary="History of N attributes of every entity (values only)")
def attrs_value(request: Request) -> JSON:
    return answer_history(request, Shape.ATTRS, values_only=True)


@router.get("/v2/attrs/{attr_name}", summary="History of one attribute of every entity")
def attr(attr_name: str, request: Request) -> JSON:
    return answer_history(request, Shape.ATTR, attr=attr_name)


@router.get("/v2/attrs/{attr_name}/value", summary="History of one attribute of every entity (values only)")
def attr_value(attr_name: str, request: Request) -> JSON:
    return answer_history(request, Shape.ATTR, attr=attr_name, values_only=True)
