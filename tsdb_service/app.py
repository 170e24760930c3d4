"""The application factory. Nothing here opens a database at import time:
the store is opened by the lifespan and closed (drained, checkpointed) by it."""

from __future__ import annotations

import logging
import os
from contextlib import asynccontextmanager
from functools import partial
from pathlib import Path

from fastapi import FastAPI
from starlette.concurrency import run_in_threadpool
from starlette.types import ASGIApp

from tsdb_service import __version__, telemetry
from tsdb_service.core.budget import ReadLimits, ReadPool
from tsdb_service.core.config import Settings, SettingsError, flag_named, get_settings
from tsdb_service.faces import export, grafana, ngsild, operator, quantumleap, ui
from tsdb_service.faces.grafana import openapi as grafana_oa
from tsdb_service.faces.operator import openapi as operator_oa
from tsdb_service.faces.quantumleap import history as quantumleap_history
from tsdb_service.faces.quantumleap import openapi as quantumleap_oa
from tsdb_service.http import rawpath
from tsdb_service.http.bodies import BodyLimit
from tsdb_service.http.budget import ReadBudgetMiddleware
from tsdb_service.http.errors import install_error_handlers
from tsdb_service.http.fastpath import FastRoutes
from tsdb_service.http.openapi import install as install_openapi
from tsdb_service.http.responses import JSON
from tsdb_service.http.store import ServiceStore
from tsdb_service.ingest import http_notify as notify
from tsdb_service.ingest import openapi as notify_oa
from tsdb_service.security import authenticates, protect
from tsdb_service.storage import open_store, redact

log = logging.getLogger("tsdb_service")


class TsdbApp(FastAPI):
    """FastAPI with the notification fast path and the history reads' fast
    path in front of everything, framework included (``ingest.http_notify``,
    ``http.fastpath``), the security layers (CORS, authentication:
    ``security.protect``) in front of all, and every HTTP request timed
    (refusals included)."""

    request_metrics: telemetry.RequestMetrics
    front: ASGIApp  # the guarded ASGI entry point; create_app sets it
    fast: FastRoutes  # the history reads served ahead of the framework; create_app sets it

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
        matched = self.fast.match(scope)
        if matched is not None:
            await self.fast.serve(self, scope, receive, send, matched)
            return
        await super().__call__(scope, receive, send)


def create_app(
    settings: Settings | None = None,
    metrics: telemetry.Metrics | None = None,
    store: ServiceStore | None = None,
    relay_dir: str | None = None,
) -> FastAPI:
    """The app. ``store``: serve this one (``http.memory.MemoryStore`` in
    route tests) instead of opening ``settings.db``; the caller closes it.
    ``relay_dir``: with ``settings.ingest_processes`` > 1, where the relay's
    sockets live (``serve`` makes it); the lifespan starts the acceptors."""
    settings = settings or get_settings()
    metrics = metrics or telemetry.Metrics()
    mqtt = mqtt_config(settings)

    @asynccontextmanager
    async def lifespan(app: FastAPI):
        if store is not None:
            app.state.store = store
            async with consuming(app, mqtt, metrics):
                yield
            return
        app.state.store = await run_in_threadpool(open_store, settings, background=True)
        metrics.attach(app.state.store)
        log.info("tsdb-service %s opened the %s", __version__, describe_database(settings))
        try:
            async with consuming(app, mqtt, metrics), accepting(app, settings, relay_dir, metrics):
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
    install_openapi(app, settings.api_key_header if authenticates(settings) else None, FEATURE_SCHEMAS)
    # One read budget for the whole process, shared by every request (core.budget).
    read_pool = ReadPool(
        settings.read_concurrency, settings.read_rows_in_flight, settings.read_queue_seconds, settings.read_max_rows
    )
    app.state.read_pool = read_pool
    metrics.attach_read_pool(read_pool)
    app.add_middleware(ReadBudgetMiddleware, limits=ReadLimits.from_settings(settings), pool=read_pool)
    app.add_middleware(
        BodyLimit,
        default=settings.max_request_body_bytes,
        larger=settings.max_body_bytes,
        larger_routes=ngsild.LARGE_BODIES,
    )
    for feature in FEATURES:
        app.include_router(feature.router)
    app.fast = FastRoutes(quantumleap_history.router.routes, FAST_PATHS, ReadLimits.from_settings(settings), read_pool)
    return app


# The hottest reads, served ahead of the framework (``http.fastpath``).
FAST_PATHS = tuple(route.path for route in quantumleap_history.ROUTES)
# Every feature with routes, in the order the router tries them.
FEATURES = (operator, notify, quantumleap, grafana, export, ui, ngsild)
# The component schemas their routes refer to (each feature's ``openapi.SCHEMAS``).
FEATURE_SCHEMAS = {
    **operator_oa.SCHEMAS,
    **notify_oa.SCHEMAS,
    **quantumleap_oa.SCHEMAS,
    **grafana_oa.SCHEMAS,
}


def mqtt_config(settings: Settings):
    """The MQTT consumer's settings (``ingest.mqtt``), None when it is off;
    a bad one is a ``SettingsError`` naming its flag (``serve`` checked it
    already, in ``check_serve``)."""
    if not settings.mqtt_url:
        return None
    from tsdb_service.ingest.mqtt.config import MqttConfig

    try:
        return MqttConfig.from_settings(settings)
    except ValueError as exc:
        raise SettingsError(flag_named(str(exc))) from None


@asynccontextmanager
async def consuming(app: FastAPI, config, metrics: telemetry.Metrics):
    """Run the MQTT consumer beside the HTTP listener while the app runs
    (once the store is open, stopped before it closes); nothing when off."""
    if config is None:
        yield
        return
    from tsdb_service.ingest.mqtt.consumer import MqttConsumer

    consumer = MqttConsumer(config, app.state.store)
    await consumer.start()
    app.state.mqtt = consumer
    metrics.attach_mqtt(consumer)
    try:
        yield
    finally:
        metrics.detach_mqtt()
        await consumer.stop()


@asynccontextmanager
async def accepting(app: FastAPI, settings: Settings, relay_dir: str | None, metrics: telemetry.Metrics):
    """With ``--ingest-processes`` N > 1: the relay (``ingest.relay``) and
    its N-1 acceptor processes (``ingest.processes``) while the app runs,
    once the store is open; the acceptors stop before the relay and the
    store close. Nothing otherwise."""
    if relay_dir is None or settings.ingest_processes < 2:
        yield
        return
    from tsdb_service.ingest.processes import LISTEN_FDS_VARIABLE, RELAY_SOCKET, Acceptors
    from tsdb_service.ingest.relay import RelayServer

    store = app.state.store

    async def values_layout(tenant: str, subscription_id: str):
        return await store.read(partial(store.values_layout, tenant, subscription_id), consistent=False)

    def observe(route: str, method: str, status: int, seconds: float) -> None:
        metrics.requests.observe({"method": method}, status, seconds, route)

    relay = RelayServer(store.write, values_layout, max_frame=2 * settings.max_body_bytes + 65536, observe=observe)
    await relay.start(str(Path(relay_dir) / RELAY_SOCKET))
    listen_fds = [int(fd) for fd in os.environ[LISTEN_FDS_VARIABLE].split(",")]
    acceptors = Acceptors(relay_dir, listen_fds, relayed=lambda: relay.relayed)
    app.state.acceptors = acceptors
    metrics.attach_ingest_processes(acceptors)
    try:
        await acceptors.start()
        yield
    finally:
        await acceptors.stop()
        await relay.close()
        metrics.detach_ingest_processes()


def create_acceptor_app(settings: Settings, relay_dir: str):
    """An acceptor process's app (``ingest.acceptor``): the notify path
    behind the same guard as the serving process's, the rest passed on."""
    from tsdb_service.ingest.acceptor import AcceptorApp
    from tsdb_service.ingest.processes import OWNER_HTTP_SOCKET, RELAY_SOCKET
    from tsdb_service.ingest.relay import RelayClient

    app = AcceptorApp(
        settings, RelayClient(), str(Path(relay_dir) / OWNER_HTTP_SOCKET), str(Path(relay_dir) / RELAY_SOCKET)
    )

    async def serve_notify(scope, receive, send) -> None:
        await notify.serve_notification(app, scope, receive, send)

    app.notify = protect(serve_notify, settings)
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
    """uvicorn factory entry point: settings from ``TSDB_*`` variables (and
    the relay's directory, which ``serve`` sets with ``--ingest-processes``)."""
    from tsdb_service.ingest.processes import RELAY_DIR_VARIABLE

    return create_app(Settings(), relay_dir=os.environ.get(RELAY_DIR_VARIABLE))
