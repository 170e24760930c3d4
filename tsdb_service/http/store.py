"""``@reads_store``: a route whose whole body reads the store, run through ``Store.read``.

FastAPI would run a plain ``def`` route in its own threadpool, a second way
off the event loop beside ``Store.read``. Routes that read the store and
are easiest written as one blocking function (Grafana, the explorer's
listings, health, the rejected store, layouts) keep their body as is and
are wrapped instead: FastAPI sees a coroutine, and the body runs through
``await store.read(..., memory_first=False)`` (the threadpool at once, as
before). Routes with async work of their own call ``store.read`` directly.
"""

from __future__ import annotations

import functools
from collections.abc import Awaitable, Callable
from typing import ParamSpec, TypeVar, cast

from starlette.requests import Request

P = ParamSpec("P")
R = TypeVar("R")


def reads_store(route: Callable[P, R]) -> Callable[P, Awaitable[R]]:
    """Wrap a plain ``def`` route that takes ``request: Request``; its
    signature and docstring (the OpenAPI description) stay the route's."""

    @functools.wraps(route)
    async def awaited(*args: P.args, **kwargs: P.kwargs) -> R:
        store = cast(Request, kwargs["request"]).app.state.store
        return await store.read(functools.partial(route, *args, **kwargs), memory_first=False)

    return awaited
