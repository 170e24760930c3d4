"""The application factory. Nothing here opens a database at import time:
the store is opened by the lifespan and closed (drained, checkpointed) by it."""

from __future__ import annotations

import gc
import logging
import sys
from contextlib import asynccontextmanager
from pathlib import Path

from fastapi import FastAPI
from starlette.concurrency import run_in_threadpool
from starlette.types import ASGIApp

from tsdb_service import __version__
from tsdb_service.core.budget import ReadBudgetMiddleware, ReadLimits
from tsdb_service.core.config import Settings, get_settings
from tsdb_service.faces import grafana, ui
from tsdb_service.faces.export import routes as export_api
from tsdb_service.faces.ngsild import routes_read as ngsild_read
from tsdb_service.faces.ngsild import write as ngsild_write
from tsdb_service.faces.operator import meta
from tsdb_service.faces.operator import metrics as metrics_
from tsdb_service.faces.quantumleap import attrs, entities, op_query, subscribe, types
from tsdb_service.http import rawpath
from tsdb_service.http.errors import install_error_handlers
from tsdb_service.http.openapi import install as install_openapi
from tsdb_service.http.responses import JSON
from tsdb_service.ingest import http_notify as notify
from tsdb_service.security import protect
from tsdb_service.storage import open_store, redact

log = logging.getLogger("tsdb_service")
WRITER_SWITCH_INTERVAL_S = 0.0002


class TsdbApp(FastAPI):
    """FastAPI with the notification fast path in front of everything,
    framework included (see api.notify), the security layers (CORS,
    authentication: ``security.protect``) in front of both, and every HTTP
    request timed (refusals included)."""

    request_metrics: metrics_.RequestMetrics
    front: ASGIApp  # the guarded ASGI entry point; create_app sets it

    async def __call__(self, scope, receive, send) -> None:
        if scope["type"] != "http":
            await self.front(scope, receive, send)
        elif notify.is_notification(scope):
            await self.request_metrics.timed(self.front, scope, receive, send, scope["path"])
        else:
            rawpath.keep_encoded_slashes(scope)  # ids, types and names with "/" as %2F
            await self.request_metrics.timed(self.front, scope, receive, send)

    async def dispatch(self, scope, receive, send) -> None:
        if notify.is_notification(scope):
            await notify.serve_notification(self, scope, receive, send)
            return
        await super().__call__(scope, receive, send)


def create_app(settings: Settings | None = None, metrics: metrics_.Metrics | None = None) -> FastAPI:
    settings = settings or get_settings()
    metrics = metrics or metrics_.Metrics()

    @asynccontextmanager
    async def lifespan(app: FastAPI):
        # The writer thread needs the GIL back after each database call; with
        # the default 5 ms switch interval a busy event loop makes every group
        # commit wait that long, which caps ingest far below what DuckDB does.
        sys.setswitchinterval(WRITER_SWITCH_INTERVAL_S)
        app.state.store = await run_in_threadpool(open_store, settings, background=True)
        metrics.attach(app.state.store)
        log.info("tsdb-service %s opened the %s", __version__, describe_database(settings))
        # Ingest allocates many short-lived objects; move everything built at
        # startup out of the collector's way and collect young objects less often.
        gc.freeze()
        gc.set_threshold(50_000, 20, 20)
        try:
            yield
        finally:
            metrics.detach()
            await run_in_threadpool(app.state.store.close)

    app = TsdbApp(
        title="tsdb-service",
        version=__version__,
        description="History of an NGSI context broker, QuantumLeap-compatible.",
        lifespan=lifespan,
        default_response_class=JSON,
        docs_url=None,  # ui serves /docs from vendored assets, not a CDN
        redoc_url=None,
    )
    app.state.settings = settings
    app.state.metrics = metrics
    app.request_metrics = metrics.requests
    app.front = protect(app.dispatch, settings)
    install_error_handlers(app)
    install_openapi(app, settings.api_key_header)
    app.add_middleware(ReadBudgetMiddleware, limits=ReadLimits.from_settings(settings))
    app.include_router(meta.router)
    app.include_router(metrics_.router)
    app.include_router(notify.router)
    app.include_router(entities.router)
    app.include_router(types.router)
    app.include_router(attrs.router)
    app.include_router(op_query.router)
    app.include_router(subscribe.router)
    app.include_router(grafana.router)
    app.include_router(export_api.router)
    app.include_router(ui.router)
    app.include_router(ngsild_write.router)
    app.include_router(ngsild_read.router)
    return app


def describe_database(settings: Settings) -> str:
    """The database a server opened, for its log: a DuckDB file's absolute
    path, or a PostgreSQL URL without its password."""
    if settings.backend == "postgresql":
        return f"PostgreSQL database at {redact(settings.db)}"
    if settings.db == ":memory:":
        return "DuckDB database in memory (nothing is kept)"
    return f"DuckDB file {Path(settings.db).resolve()}"


def create_app_from_env() -> FastAPI:
    """uvicorn factory entry point: settings from ``TSDB_*`` variables."""
    return create_app(Settings())
