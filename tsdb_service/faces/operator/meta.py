"""Service metadata: version, health and the API index, as QuantumLeap has
them, and the Prometheus metrics (``telemetry``) an operator scrapes."""

from __future__ import annotations

from fastapi import APIRouter, Request
from starlette.responses import Response

from tsdb_service import __version__
from tsdb_service.faces.operator import openapi as ops_oa
from tsdb_service.http import openapi as oa
from tsdb_service.http.responses import JSON
from tsdb_service.http.store import reports_store, store_of

router = APIRouter(tags=["meta"])
METRICS_CONTENT_TYPE = "text/plain; version=0.0.4; charset=utf-8"


@router.get("/version", **oa.spec(ok_=oa.ok(ops_oa.VERSION), errors_=()))
def version() -> JSON:
    """The release only, as QuantumLeap answers: which backend and how it is
    configured are the operator's business, not every client's."""
    return JSON({"version": __version__})


# What a health probe may say: the status (the HTTP code carries it too, for
# an orchestrator) and a short human reason when it is not "pass". Counters
# of commits and writes would tell anyone how busy the service is.
_HEALTH_KEYS = ("status", "output")


@router.get("/health", **ops_oa.HEALTH)
@reports_store
def health(request: Request) -> JSON:
    report = store_of(request).health()
    # The MQTT consumer (ingest.mqtt) and the acceptor processes (ingest.processes), when on.
    for part in (getattr(request.app.state, "mqtt", None), getattr(request.app.state, "acceptors", None)):
        problem = part.health() if part is not None else None
        if problem is not None and report["status"] == "pass":
            # Still serving: HTTP ingest and reads work while the broker or an acceptor is away.
            report = {**report, "status": "warn", "output": problem}
    status = 503 if report["status"] == "fail" else 200
    public = {key: report[key] for key in _HEALTH_KEYS if key in report}
    return JSON(public, status_code=status, headers={"Content-Type": "application/health+json"})


# QuantumLeap's index also names /v2/subscriptions and /v2/types, which
# neither it nor we serve; only URLs that answer are listed here.
API_INDEX = {
    "notify_url": "/v2/notify",
    "subscribe_url": "/v2/subscribe",
    "entities_url": "/v2/entities",
    "attributes_url": "/v2/attrs",
    "op_query_url": "/v2/op/query",
}


@router.get("/v2/", **oa.spec(ok_=oa.ok(ops_oa.API_INDEX), errors_=oa.AUTH))
@router.get("/v2", **oa.spec(ok_=oa.ok(ops_oa.API_INDEX), errors_=oa.AUTH))
def api_index() -> JSON:
    return JSON(API_INDEX)


@router.get("/metrics", summary="Prometheus metrics (text exposition format)", **ops_oa.METRICS)
@reports_store  # in the threadpool: the store sizes may query the database
def metrics_endpoint(request: Request) -> Response:
    return Response(request.app.state.metrics.render(), media_type=METRICS_CONTENT_TYPE)
