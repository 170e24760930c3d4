"""How long an ASGI handler took to answer, and with what status: the one
wrapper behind the request histogram (``telemetry.RequestMetrics``) and the
acceptors' reports of their answers (``ingest.acceptor``)."""

from __future__ import annotations

import time
from collections.abc import Awaitable, Callable
from typing import Any

ASGIHandler = Callable[[Any, Any, Any], Awaitable[None]]


async def timed(handler: ASGIHandler, scope, receive, send, record: Callable[[int, float], None]) -> None:
    """Run ``handler``, then ``record(status, seconds)``, also when it
    raised; the status is the one it started its answer with (500 if none)."""
    status = 500

    async def send_status(message) -> None:
        nonlocal status
        if message["type"] == "http.response.start":
            status = message["status"]
        await send(message)

    start = time.perf_counter()
    try:
        await handler(scope, receive, send_status)
    finally:
        record(status, time.perf_counter() - start)
