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


@router.get("/v2/")
@router.get("/v2")
def api_index() -> JSON:
    return JSON(
        {
            "notify_url": "/v2/notify",
            "subscriptions_url": "/v2/subscriptions",
            "entities_url": "/v2/entities",
            "types_url": "/v2/types",
            "attributes_url": "/v2/attrs",
        }
    )
