"""Request bodies are limited while they are read, on every route.

A route that reads its body whole and then checks its size has already
paid for it: a 256 MiB POST to a 1 MiB route cost 512 MiB before its 400.
``BodyLimit`` sits in front of every framework route (notifications keep
their own reader, which still keeps the first bytes of an oversized
notification for the rejected store): a ``Content-Length`` over the
route's limit is answered 413 before a byte of the body is read, and a
body without one is counted as it arrives and cut off with a 413 the moment
it passes the limit. Routes then read bodies as usual (``request.body()``,
FastAPI's ``Body()``), knowing they are within the limit.

Limits: ``TSDB_MAX_BODY_BYTES`` for the routes that take what a broker
sends (the NGSI-LD temporal writes, ``larger``), ``TSDB_MAX_REQUEST_BODY_BYTES``
for every other route (queries, Grafana, layouts).
"""

from __future__ import annotations

from collections.abc import Iterable

import orjson
from starlette.exceptions import HTTPException

from tsdb_service.http import problems


class BodyTooLarge(HTTPException):
    """Raised from ``receive`` when the body passes the limit: an
    ``HTTPException`` so FastAPI's own body parsing lets it through to the
    error handler (413 in the path's error shape)."""

    def __init__(self, limit: int, setting: str):
        super().__init__(413, f"the request body is larger than {limit} bytes ({setting})")


class BodyLimit:
    """ASGI middleware: ``default`` bytes for every request body, ``larger``
    for requests whose ``(method, path prefix)`` is listed."""

    def __init__(self, app, default: int, larger: int, larger_routes: Iterable[tuple[str, str]]):
        self.app = app
        self.default, self.larger = default, larger
        self.larger_routes = tuple(larger_routes)

    def limit_of(self, method: str, path: str) -> tuple[int, str]:
        for route_method, prefix in self.larger_routes:
            if method == route_method and path.startswith(prefix):
                return self.larger, "TSDB_MAX_BODY_BYTES"
        return self.default, "TSDB_MAX_REQUEST_BODY_BYTES"

    async def __call__(self, scope, receive, send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        path, root = scope["path"], scope.get("root_path", "")
        limit, setting = self.limit_of(scope["method"], path[len(root) :] if root and path.startswith(root) else path)
        declared = _content_length(scope["headers"])
        if declared is not None and declared > limit:
            await _refuse(send, scope["path"], BodyTooLarge(limit, setting))
            return
        seen = 0

        async def limited():
            nonlocal seen
            message = await receive()
            if message["type"] == "http.request":
                seen += len(message.get("body", b""))
                if seen > limit:
                    raise BodyTooLarge(limit, setting)
            return message

        await self.app(scope, limited, send)


def _content_length(headers) -> int | None:
    for name, value in headers:
        if name == b"content-length":
            return int(value) if value.isdigit() else None
    return None


async def _refuse(send, path: str, exc: BodyTooLarge) -> None:
    """413 in the path's error shape (before the framework, so rendered here)."""
    if problems.is_ngsild_path(path):
        body = orjson.dumps(problems.problem("InvalidRequest", 413, exc.detail))
    else:
        body = orjson.dumps({"error": "PayloadTooLarge", "description": exc.detail})
    headers = [
        (b"content-type", b"application/json"),
        (b"content-length", str(len(body)).encode()),
        (b"connection", b"close"),
    ]
    await send({"type": "http.response.start", "status": 413, "headers": headers})
    await send({"type": "http.response.body", "body": body})
