"""An acceptor process's application (``--ingest-processes``; ``ingest.relay``).

It serves the notify URLs with the serving process's own code
(``ingest.http_notify.serve_notification``), against a store that holds
nothing: the parse runs here, and every write goes to the owner through the
relay. Every other request (history reads, the explorer, health, layouts,
deletes) is passed whole to the owner's HTTP server on a Unix socket and its
answer streamed back, so a client sees one service whichever process the
kernel gave its connection to.

Invariants:

* **Nothing is stored here.** The acceptor keeps no cache of the store: a
  ``values``-format notification asks the owner for its layout each time,
  so a layout registered a moment ago is the one used.
* **Same answers.** A notification gets the answer the owner would give
  (the same code, and the owner's refusals relayed as they are); a passed
  request gets the owner's status, headers and body bytes unchanged (no
  decompression, no re-encoding). Hop-by-hop headers are dropped both ways.
* **The owner authenticates what it serves.** A passed request keeps its
  headers, credentials included, and the owner decides; notifications are
  checked here by the same guard (``security.protect``, applied by
  ``app.create_acceptor_app``).
"""

from __future__ import annotations

import asyncio
import contextvars
import logging
import os
from collections.abc import Callable
from typing import Any

import httpx
from starlette.datastructures import State

from tsdb_service.core import asgitiming
from tsdb_service.core.config import Settings
from tsdb_service.core.errors import TsdbError
from tsdb_service.ingest.http_notify import NOTIFY_PATHS
from tsdb_service.ingest.relay import RelayClient
from tsdb_service.parse import ValuesLayout

log = logging.getLogger(__name__)

_HOP_BY_HOP = frozenset(
    {
        b"connection",
        b"keep-alive",
        b"proxy-authenticate",
        b"proxy-authorization",
        b"te",
        b"trailer",
        b"transfer-encoding",
        b"upgrade",
    }
)
_OWNER_GONE = (
    b'{"error":"ServiceUnavailable","description":"the process that owns the database is not reachable; try again"}'
)
REPORT_AT = 1000  # answers kept before they are reported to the owner (and at least once a second)
# Layouts the owner gave for the parse being retried (see RelayedStore.read).
_FETCHED: contextvars.ContextVar[dict[tuple[str, str], ValuesLayout | None] | None] = contextvars.ContextVar(
    "tsdb_fetched_layouts", default=None
)


class _LayoutNeeded(Exception):
    def __init__(self, tenant: str, subscription_id: str):
        super().__init__(tenant, subscription_id)
        self.key = (tenant, subscription_id)


class RelayedStore:
    """The store as the notify path sees it in an acceptor: ``read`` runs
    the parse here, ``write`` relays, ``values_layout`` asks the owner."""

    backend = "relay"

    def __init__(self, relay: RelayClient):
        self.relay = relay

    async def read(self, fn: Callable[[], Any], *, memory_first: bool = True, consistent: bool = True) -> Any:
        """Run the parse ``fn`` (inline when ``memory_first``, else on a
        thread). A ``values`` layout it needs is fetched from the owner and
        the parse run again with it: a lookup cannot wait inside a parse."""
        fetched: dict[tuple[str, str], ValuesLayout | None] = {}
        token = _FETCHED.set(fetched)
        try:
            for _ in range(4):
                try:
                    return fn() if memory_first else await asyncio.to_thread(fn)
                except _LayoutNeeded as need:
                    fetched[need.key] = await self.relay.values_layout(*need.key)
            raise TsdbError("a notification asked for more 'values' layouts than one")
        finally:
            _FETCHED.reset(token)

    def values_layout(self, tenant: str, subscription_id: str) -> ValuesLayout | None:
        fetched = _FETCHED.get()
        if fetched is not None and (tenant, subscription_id) in fetched:
            return fetched[(tenant, subscription_id)]
        raise _LayoutNeeded(tenant, subscription_id)

    async def write(self, op: Any) -> None:
        await self.relay.write(op)


class AcceptorApp:
    """The ASGI app of an acceptor: ``notify`` (the guarded notify path)
    for the notify URLs, the owner for everything else."""

    def __init__(self, settings: Settings, relay: RelayClient, owner_http: str, relay_path: str):
        self.state = State()
        self.state.settings = settings
        self.state.store = RelayedStore(relay)
        self.relay = relay
        self.relay_path = relay_path
        self.owner = httpx.AsyncClient(
            transport=httpx.AsyncHTTPTransport(uds=owner_http),
            base_url="http://tsdb-owner",
            timeout=httpx.Timeout(None, connect=10.0),
        )
        self.notify: Callable[[Any, Any, Any], Any] | None = None  # set by app.create_acceptor_app
        self.on_owner_lost: Callable[[], None] = lambda: None
        self._timings: list[tuple[str, str, int, float]] = []  # answered, not yet reported to the owner

    async def __call__(self, scope, receive, send) -> None:
        kind = scope["type"]
        if kind == "lifespan":
            await self._lifespan(receive, send)
        elif kind == "http" and scope["method"] == "POST" and scope["path"] in NOTIFY_PATHS:
            await self._timed_notify(scope, receive, send)
        elif kind == "http":
            await self.pass_to_owner(scope, receive, send)
        # websockets: none are served

    async def _lifespan(self, receive, send) -> None:
        while True:
            message = await receive()
            if message["type"] == "lifespan.startup":
                try:
                    await self.relay.connect(self.relay_path)
                except OSError as exc:
                    await send({"type": "lifespan.startup.failed", "message": f"the owner's relay: {exc}"})
                    return
                loop = asyncio.get_running_loop()
                self._background = [loop.create_task(self._watch_owner()), loop.create_task(self._report_every(1.0))]
                await send({"type": "lifespan.startup.complete"})
            elif message["type"] == "lifespan.shutdown":
                self._report_soon()
                await asyncio.sleep(0)  # the last timings leave before the connection closes
                self.relay.close()
                await self.owner.aclose()
                await send({"type": "lifespan.shutdown.complete"})
                return

    async def _timed_notify(self, scope, receive, send) -> None:
        """The notify path, each answer's status and time kept for the owner's ``/metrics``."""
        assert self.notify is not None

        def keep(status: int, seconds: float) -> None:
            self._timings.append((scope["path"], "POST", status, seconds))
            if len(self._timings) >= REPORT_AT:
                self._report_soon()

        await asgitiming.timed(self.notify, scope, receive, send, keep)

    def _report_soon(self) -> None:
        timings, self._timings = self._timings, []
        if timings and not self.relay.lost.is_set():
            task = asyncio.get_running_loop().create_task(self.relay.report(timings))
            task.add_done_callback(_ignore_failure)

    async def _report_every(self, seconds: float) -> None:
        while not self.relay.lost.is_set():
            await asyncio.sleep(seconds)
            self._report_soon()

    async def _watch_owner(self) -> None:
        await self.relay.lost.wait()
        log.warning("ingest process %s: the serving process is gone; stopping", os.getpid())
        self.on_owner_lost()

    async def pass_to_owner(self, scope, receive, send) -> None:
        """The request, whole, to the owner; its answer streamed back."""
        target = scope.get("raw_path") or scope["path"].encode()
        if scope.get("query_string"):
            target += b"?" + scope["query_string"]
        headers = [(k, v) for k, v in scope["headers"] if k not in _HOP_BY_HOP]
        has_body = any(k in (b"content-length", b"transfer-encoding") for k, _ in scope["headers"])
        request = self.owner.build_request(
            scope["method"],
            "http://tsdb-owner" + target.decode("latin-1"),
            headers=headers,
            content=_body(receive) if has_body else None,
        )
        try:
            response = await self.owner.send(request, stream=True)
        except httpx.TransportError as exc:
            log.warning("ingest process %s could not pass a request to the serving process: %s", os.getpid(), exc)
            await _answer(send, 503, _OWNER_GONE)
            return
        try:
            await send(
                {
                    "type": "http.response.start",
                    "status": response.status_code,
                    "headers": [(k.lower(), v) for k, v in response.headers.raw if k.lower() not in _HOP_BY_HOP],
                }
            )
            async for chunk in response.aiter_raw():
                await send({"type": "http.response.body", "body": chunk, "more_body": True})
            await send({"type": "http.response.body", "body": b""})
        finally:
            await response.aclose()


def _ignore_failure(task: asyncio.Task) -> None:
    if not task.cancelled():
        task.exception()  # timings are lost with the owner; nothing else is


async def _body(receive):
    while True:
        message = await receive()
        if message["type"] == "http.disconnect":
            return
        yield message.get("body", b"")
        if not message.get("more_body"):
            return


async def _answer(send, status: int, body: bytes) -> None:
    headers = [(b"content-type", b"application/json"), (b"content-length", str(len(body)).encode())]
    await send({"type": "http.response.start", "status": status, "headers": headers})
    await send({"type": "http.response.body", "body": body})
