"""The HTTP side of read budgets (``core.budget``): a fresh budget per read
request, and no answer larger than the response-size limit."""

from __future__ import annotations

import orjson

from tsdb_service.core import budget
from tsdb_service.core.budget import NARROW, QueryTooLarge, ReadLimits

_BUDGETED_METHODS = frozenset({"GET", "HEAD", "POST"})


class ReadBudgetMiddleware:
    """Gives every read request (GET, HEAD, POST; deletes and notifications
    are not reads) a fresh budget, and refuses an answer whose rendered size
    is over ``max_response_bytes`` before any of it is sent."""

    def __init__(self, app, limits: ReadLimits):
        self.app = app
        self.limits = limits

    async def __call__(self, scope, receive, send) -> None:
        if scope["type"] != "http" or scope["method"] not in _BUDGETED_METHODS:
            await self.app(scope, receive, send)
            return
        token = budget.begin(self.limits)
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
