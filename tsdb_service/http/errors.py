"""The one place errors become HTTP responses: in the NGSI shape
``{"error": ..., "description": ...}``, and under ``/ngsi-ld/`` as NGSI-LD
ProblemDetails (``http.problems``)."""

from __future__ import annotations

import logging
import uuid

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.requests import ClientDisconnect
from starlette.routing import Match

from tsdb_service.core.errors import TsdbError
from tsdb_service.http import problems as ld
from tsdb_service.http.responses import JSON

log = logging.getLogger("tsdb_service")

REQUEST_ID_HEADER = "X-Request-Id"  # on every 500: the id its log record is filed under
_HTTP_NAMES = {404: "NotFound", 405: "MethodNotAllowed", 413: "PayloadTooLarge", 415: "UnsupportedMediaType"}


def internal_error(context: str, exc: BaseException | None = None) -> tuple[str, dict[str, str]]:
    """Log ``exc`` (default: the one being handled) under a fresh request id
    and return ``(id, body)``: the client learns the id, never the internals
    (class names, paths, SQL), which stay in the operator's log."""
    request_id = uuid.uuid4().hex
    log.error("%s [request id %s]", context, request_id, exc_info=exc or True)
    return request_id, {
        "error": "InternalError",
        "description": f"internal error; the operator can find it in the log under request id {request_id}",
    }


_METHODS = ("GET", "HEAD", "POST", "PUT", "PATCH", "DELETE")


def allowed_methods(request: Request) -> str:
    """Every method some route accepts on this path. A path may have one
    route per method, and the router's 405 names only the first route's, so
    ask the router about each method in turn (only ever on a 405)."""
    allowed = []
    for method in _METHODS:
        probe = {**request.scope, "method": method}
        if any(route.matches(probe)[0] is Match.FULL for route in request.app.router.routes):
            allowed.append(method)
    return ", ".join(allowed)


def _error(request: Request, error: str, description: str, status: int, ld_type: str, headers=None) -> JSON:
    """One error answer, in the shape of the API the path belongs to."""
    if ld.is_ngsild_path(request.url.path):
        return JSON(
            ld.problem(ld_type, status, description), status_code=status, headers=headers, media_type=ld.MEDIA_TYPE
        )
    return JSON({"error": error, "description": description}, status_code=status, headers=headers)


def client_disconnected(request: Request) -> JSON:
    """A client that closed its connection before its body was complete: not
    a bug, and nobody is left to read an answer. One warning line (no
    traceback), and a 400 so the request metric does not count a server error;
    nothing was done with the partial body."""
    client = request.client
    peer = f"{client.host}:{client.port}" if client else "a client"
    log.warning(
        "%s %s from %s abandoned: the client disconnected before sending the whole body "
        "(Content-Length %s); nothing was done",
        request.method,
        request.url.path,
        peer,
        request.headers.get("content-length"),
    )
    return _error(
        request, "ClientDisconnected", "the client disconnected before sending the whole body", 400, "BadRequestData"
    )


def error_response(request: Request, exc: TsdbError) -> JSON:
    """A ``TsdbError`` as the answer of the API the path belongs to (with
    the headers it carries, such as ``ServerBusy``'s ``Retry-After``)."""
    return _error(request, exc.error, exc.description, exc.status, exc.ld_type, getattr(exc, "headers", None))


def unexpected_response(request: Request, exc: BaseException) -> JSON:
    """A bug: 500, the internals in the log under a request id, never in the answer."""
    request_id, body = internal_error(f"unhandled error in {request.method} {request.url.path}", exc)
    return _error(request, body["error"], body["description"], 500, "InternalError", {REQUEST_ID_HEADER: request_id})


def install_error_handlers(app: FastAPI) -> None:
    @app.exception_handler(TsdbError)
    async def tsdb_error(request: Request, exc: TsdbError) -> JSON:
        return error_response(request, exc)

    @app.exception_handler(RequestValidationError)
    async def validation_error(request: Request, exc: RequestValidationError) -> JSON:
        problems = "; ".join(
            f"{'.'.join(str(p) for p in err.get('loc', ())[1:]) or 'request'}: {err.get('msg')}" for err in exc.errors()
        )
        return _error(request, "BadRequest", problems or "invalid request", 400, "BadRequestData")

    @app.exception_handler(ClientDisconnect)
    async def disconnected(request: Request, exc: ClientDisconnect) -> JSON:
        return client_disconnected(request)

    @app.exception_handler(StarletteHTTPException)
    async def http_error(request: Request, exc: StarletteHTTPException) -> JSON:
        if isinstance(exc.__cause__, ClientDisconnect):  # FastAPI reading a Body() parameter
            return client_disconnected(request)
        name = _HTTP_NAMES.get(exc.status_code, "BadRequest" if exc.status_code < 500 else "InternalError")
        headers = dict(exc.headers or {})
        if exc.status_code == 405:
            headers["Allow"] = allowed_methods(request) or headers.get("Allow", "")
        return _error(request, name, str(exc.detail), exc.status_code, ld.http_ld_type(exc.status_code), headers)

    @app.exception_handler(Exception)
    async def unexpected(request: Request, exc: Exception) -> JSON:
        return unexpected_response(request, exc)
