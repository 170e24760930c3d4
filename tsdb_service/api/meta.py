"""Service metadata: version, health and the API index, as QuantumLeap has them."""

from __future__ import annotations

from fastapi import APIRouter, Request

from .. import __version__
from .responses import JSON

router = APIRouter(tags=["meta"])


@router.get("/version")
def version(request: Request) -> JSON:
    return JSON({"version": __version__, "backend": request.app.state.store.backend})


@router.get("/health")
def health(request: Request) -> JSON:
    report = request.app.state.store.health()
    status = 200 if report["status"] == "pass" else 503
    return JSON(report, status_code=status, headers={"Content-Type": "application/health+json"})


# QuantumLeap's index also names /v2/subscriptions and /v2/types, which
# neither it nor we serve; only URLs that answer are listed here.
API_INDEX = {
    "notify_url": "/v2/notify",
    "subscribe_url": "/v2/subscribe",
    "entities_url": "/v2/entities",
    "attributes_url": "/v2/attrs",
    "op_query_url": "/v2/op/query",
}


@router.get("/v2/")
@router.get("/v2")
def api_index() -> JSON:
    return JSON(API_INDEX)
