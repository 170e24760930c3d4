"""How a route reaches the store: ``store_of(request)``, typed as the seams.

Routes see the store only as ``ServiceStore``: the read seam (``read.Reader``:
the querier and the awaited ``read``), the write seam (``write.Writer``), and
the few registrations and reports routes answer with. ``storage`` (which
backend, its connections, its maintenance) stays out of every route's reach.

``@reads_store``: a route whose whole body reads the store, run through ``Store.read``.

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
from typing import Any, ParamSpec, Protocol, TypeVar, cast

from starlette.requests import Request

from tsdb_service.core.backup import BackupReport
from tsdb_service.parse import ValuesLayout
from tsdb_service.read import Reader
from tsdb_service.write import Writer

P = ParamSpec("P")
R = TypeVar("R")


class ServiceStore(Reader, Writer, Protocol):
    """What the HTTP layer may use of the store."""

    backend: str

    def values_layout(self, tenant: str, subscription_id: str) -> ValuesLayout | None:
        """A registered ``values``-format layout (memory first; see ``storage.store``)."""
        ...

    def layouts(self, tenant: str) -> dict[str, ValuesLayout]:
        """The tenant's registered layouts by subscription id."""
        ...

    def rejected_page(
        self, tenant: str | None, limit: int, offset: int, max_bytes: int
    ) -> tuple[list[dict[str, Any]], int | None]:
        """Rejected notifications, newest first, paged by count and bytes."""
        ...

    def health(self) -> dict[str, Any]:
        """The ``/health`` report."""
        ...

    def backup(self, path: str) -> BackupReport:
        """A consistent, checked copy of the store in the new file ``path``
        (blocking: run it off the loop); ``BackupRefused`` where a backend
        has its own tools."""
        ...


def store_of(request: Request) -> ServiceStore:
    """The app's store, as the seams (the lifespan opened it)."""
    return cast(ServiceStore, request.app.state.store)


def app_store(app: Any) -> ServiceStore:
    """``store_of`` for code that has the app but no ``Request`` (the notify fast path)."""
    return cast(ServiceStore, app.state.store)


def reads_store(route: Callable[P, R]) -> Callable[P, Awaitable[R]]:
    """Wrap a plain ``def`` route that takes ``request: Request``; its
    signature and docstring (the OpenAPI description) stay the route's. The
    read sees every write acknowledged before it."""
    return _wrapped(route, consistent=True)


def reports_store(route: Callable[P, R]) -> Callable[P, Awaitable[R]]:
    """``reads_store`` for reports about the service itself (health,
    metrics): they answer at once, without waiting for the ingest log."""
    return _wrapped(route, consistent=False)


def _wrapped(route: Callable[P, R], consistent: bool) -> Callable[P, Awaitable[R]]:
    @functools.wraps(route)
    async def awaited(*args: P.args, **kwargs: P.kwargs) -> R:
        store = store_of(cast(Request, kwargs["request"]))
        read = functools.partial(route, *args, **kwargs)
        return await store.read(read, memory_first=False, consistent=consistent)

    return awaited
