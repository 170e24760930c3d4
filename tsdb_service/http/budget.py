"""The HTTP side of read budgets (``core.budget``): a fresh budget per read
request, sharing the process's ``ReadPool`` under the tenant the request
names, and no answer larger than the response-size limit."""

from __future__ import annotations

from urllib.parse import parse_qsl

import orjson

from tsdb_service.core import budget
from tsdb_service.core.budget import NARROW, QueryTooLarge, ReadLimits, ReadPool

_BUDGETED_METHODS = frozenset({"GET", "HEAD", "POST"})
# Reports about the service answer at once, never queued behind reads.
_UNPOOLED_PATHS = frozenset({"/health", "/version", "/metrics"})
_TENANT_HEADERS = (b"fiware-service", b"ngsild-tenant")
_MAX_TENANT_KEY = 64


class ReadBudgetMiddleware:
    """Gives every read request (GET, HEAD, POST; deletes and notifications
    are not reads) a fresh budget in ``pool``, and refuses an answer whose
    rendered size is over ``max_response_bytes`` before any of it is sent."""

    def __init__(self, app, limits: ReadLimits, pool: ReadPool | None = None):
        self.app = app
        self.limits = limits
        self.pool = pool

    async def __call__(self, scope, receive, send) -> None:
        if scope["type"] != "http" or scope["method"] not in _BUDGETED_METHODS:
            await self.app(scope, receive, send)
            return
        pool = None if scope["path"] in _UNPOOLED_PATHS else self.pool
        token = budget.begin(self.limits, pool, tenant_key(scope) if pool is not None else "")
        try:
            await self.app(scope, receive, _SizeGuard(send, self.limits.max_response_bytes))
        finally:
            budget.end(token)


class _SizeGuard:
    """An ASGI ``send`` that swaps an oversized answer for a 422. Answers are
    rendered whole with a Content-Length (``http.responses.JSON``), so the
    size is known from the first message."""

    __slots__ = ("_limit", "_refused", "_send")

    def __init__(self, send, limit: int):
        self._send = send
        self._limit = limit
        self._refused = False

    async def __call__(self, message) -> None:
        kind = message["type"]
        if kind == "http.response.start":
            size = _content_length(message.get("headers", ()))
            if size is not None and size > self._limit and message.get("status", 200) < 300:
                self._refused = True
                await self._refuse(size)
                return
        elif kind == "http.response.body" and self._refused:
            return  # the oversized body is dropped; the 422 went out whole
        await self._send(message)

    async def _refuse(self, size: int) -> None:
        body = orjson.dumps(
            QueryTooLarge(
                f"the answer would be {size} bytes, more than the {self._limit} allowed "
                f"(TSDB_READ_MAX_RESPONSE_BYTES); {NARROW}"
            ).body()
        )
        await self._send(
            {
                "type": "http.response.start",
                "status": QueryTooLarge.status,
                "headers": [(b"content-type", b"application/json"), (b"content-length", str(len(body)).encode())],
            }
        )
        await self._send({"type": "http.response.body", "body": body})


def _content_length(headers) -> int | None:
    for name, value in headers:
        if name.lower() == b"content-length":
            try:
                return int(value)
            except ValueError:
                return None
    return None


def tenant_key(scope) -> str:
    """The tenant a request names, for sharing the read pool fairly (not
    to authorise: the routes do that): its tenant header, else Grafana's
    ``service`` parameter, lower-cased and cut short."""
    for name, value in scope.get("headers", ()):
        if name in _TENANT_HEADERS and value.strip():
            return value.decode("latin-1").strip().lower()[:_MAX_TENANT_KEY]
    query = scope.get("query_string", b"")
    if b"service" in query:
        for name, value in parse_qsl(query.decode("latin-1")):
            if name == "service" and value.strip():
                return value.strip().lower()[:_MAX_TENANT_KEY]
    return ""
