"""The relay between the ingest processes and the process that owns the database.

With ``--ingest-processes N`` (DuckDB), N-1 *acceptor* processes share the
HTTP port with the serving process (``SO_REUSEPORT``: the kernel spreads new
connections over them). An acceptor takes a notification as the serving
process does (body limits, Content-Type, authentication, the parse and its
validation, the same code), then hands the write it parsed to the *owner*,
the one process with the database open, over a Unix socket: one frame per
write, answered by one frame. The owner writes it through its own store
(the ingest log, the group commit) and answers; only then does the acceptor
answer the broker. The acceptors take the work that holds one process's
interpreter lock longest (HTTP, the parse: 73% of it at 64 connections),
and the owner keeps what must have one owner.

Invariants:

* **Acknowledged is durable.** The owner answers a frame 200 only when
  ``store.write`` returned, that is when the record is in the ingest log,
  synced. An acceptor answers 200 only on that answer.
* **One log, one owner.** An acceptor holds nothing of the store: row ids,
  log positions, replay after a crash, deletes waiting for what was
  acknowledged before them are the owner's, as with one process. So a read,
  which the owner serves, sees every write acknowledged before it, whichever
  process took the write (read-your-writes).
* **Refused is kept.** A notification an acceptor refuses is sent to the
  owner's rejected store (``RecordRejected``) before the 4xx goes out, as
  the serving process does; a refusal the owner makes (``NotStorable``,
  503) comes back as the same error.
* **A frame is bounded.** The owner refuses a frame longer than
  ``max_frame`` (twice the notification body limit: a parsed notification
  is never much bigger than its JSON) and drops that connection; the
  acceptor starts again (``ingest.processes``).

Failure modes: the owner stops or is killed: every write in flight gets 503
(nothing acknowledged), and acceptors exit when their connection closes. An
acceptor is killed: what it had relayed was written or not, as with a crash
of one process (acknowledged writes are in the log); the owner starts it
again.

Frames: ``<length u32><id u64><kind u8>payload`` to the owner,
``<length u32><id u64><status u16>payload`` back; ``length`` counts the
payload only.
"""

from __future__ import annotations

import asyncio
import base64
import contextlib
import logging
import os
import struct
from collections.abc import Awaitable, Callable
from datetime import datetime
from typing import Any

import orjson

from tsdb_service.core.errors import TsdbError, Unavailable
from tsdb_service.core.model import RejectedNotification
from tsdb_service.http.server import CoalescingTransport
from tsdb_service.parse import ValuesLayout
from tsdb_service.write import codec
from tsdb_service.write.ops import AppendSamples, RecordRejected

log = logging.getLogger(__name__)

REQUEST = struct.Struct("<IQB")
ANSWER = struct.Struct("<IQH")
APPEND, REJECTED, LAYOUT, TIMINGS = 1, 2, 3, 4
OK = 200
_OWNER_GONE = "the process that owns the database is not reachable; nothing was stored"


# --- what a frame carries -------------------------------------------------------------------


def encode_rejected(op: RecordRejected) -> bytes:
    r = op.rejected
    return orjson.dumps(
        {
            "tenant": r.tenant,
            "received_at": r.received_at,
            "error": r.error,
            "description": r.description,
            "headers": r.headers,
            "body": base64.b64encode(r.body).decode(),
            "body_size": r.body_size,
            "body_truncated": r.body_truncated,
            "topic": r.topic,
        }
    )


def decode_rejected(payload: bytes) -> RecordRejected:
    doc = orjson.loads(payload)
    doc["received_at"] = datetime.fromisoformat(doc["received_at"])
    doc["body"] = base64.b64decode(doc["body"])
    return RecordRejected(RejectedNotification(**doc))


def layout_answer(layout: ValuesLayout | None) -> bytes:
    if layout is None:
        return b"null"
    return orjson.dumps({"attrs": list(layout.attrs), "entityId": layout.entity_id, "entityType": layout.entity_type})


def layout_of(payload: bytes) -> ValuesLayout | None:
    doc = orjson.loads(payload)
    return None if doc is None else ValuesLayout(tuple(doc["attrs"]), doc["entityId"], doc["entityType"])


def error_answer(exc: TsdbError) -> bytes:
    return orjson.dumps({"error": exc.error, "description": exc.description, "ld_type": exc.ld_type})


def error_of(status: int, payload: bytes) -> TsdbError:
    doc = orjson.loads(payload)
    return TsdbError(doc["description"], error=doc["error"], status=status, ld_type=doc["ld_type"])


# --- the owner's side -----------------------------------------------------------------------


class RelayServer:
    """The owner's end: takes frames from acceptors and writes through
    ``write`` (the store's ``write``); ``values_layout`` answers layout
    lookups (awaited: on PostgreSQL a miss reads the database)."""

    def __init__(
        self,
        write: Callable[[AppendSamples | RecordRejected], Awaitable[None]],
        values_layout: Callable[[str, str], Awaitable[ValuesLayout | None]],
        max_frame: int,
        observe: Callable[[str, str, int, float], None] = lambda route, method, status, seconds: None,
    ):
        self.write = write
        self.values_layout = values_layout
        self.max_frame = max_frame
        self.observe = observe  # one request an acceptor answered: route, method, status, seconds (/metrics)
        self.relayed = 0  # writes stored for acceptors (samples and refusals), for /metrics
        self._server: asyncio.AbstractServer | None = None
        self._tasks: set[asyncio.Task] = set()

    async def start(self, path: str) -> None:
        loop = asyncio.get_running_loop()
        self._server = await loop.create_unix_server(lambda: _OwnerSide(self), path=path)
        os.chmod(path, 0o600)

    async def close(self) -> None:
        if self._server is not None:
            self._server.close()
            with contextlib.suppress(Exception):
                await asyncio.wait_for(self._server.wait_closed(), 5)
        if self._tasks:
            await asyncio.wait(self._tasks, timeout=30)

    def handle(self, side: _OwnerSide, frame_id: int, kind: int, payload: bytes) -> None:
        task = asyncio.ensure_future(self._answer(side, frame_id, kind, payload))
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)

    async def _answer(self, side: _OwnerSide, frame_id: int, kind: int, payload: bytes) -> None:
        try:
            if kind == APPEND:
                await self.write(codec.decode(payload))
                answer = b""
                self.relayed += 1
            elif kind == REJECTED:
                await self.write(decode_rejected(payload))
                answer = b""
                self.relayed += 1
            elif kind == LAYOUT:
                tenant, subscription = orjson.loads(payload)
                answer = layout_answer(await self.values_layout(tenant, subscription))
            elif kind == TIMINGS:
                for route, method, status, seconds in orjson.loads(payload):
                    self.observe(route, method, status, seconds)
                answer = b""
            else:
                raise TsdbError(f"an ingest process sent a frame of unknown kind {kind}")
            status = OK
        except TsdbError as exc:
            status, answer = exc.status, error_answer(exc)
        except Exception:
            log.exception("a write relayed by an ingest process failed")
            status, answer = 500, error_answer(TsdbError("the relayed write failed; see the service log"))
        side.answer(frame_id, status, answer)


class _Framed(asyncio.Protocol):
    """One end of a relay connection: frames in (``incoming`` is their
    header: length, id, a code), writes out through
    ``http.server.CoalescingTransport`` (a turn's frames leave in one write)."""

    incoming: struct.Struct

    def __init__(self) -> None:
        self.buffer = bytearray()
        self.transport: CoalescingTransport | None = None

    def connection_made(self, transport) -> None:
        self.transport = CoalescingTransport(transport, asyncio.get_running_loop())

    def connection_lost(self, exc) -> None:
        self.transport = None

    def send(self, data: bytes) -> None:
        if self.transport is not None and not self.transport.is_closing():
            self.transport.write(data)

    def data_received(self, data: bytes) -> None:
        buffer, header = self.buffer, self.incoming
        buffer += data
        start = 0
        while len(buffer) - start >= header.size:
            length, frame_id, code = header.unpack_from(buffer, start)
            if not self.acceptable(length):
                buffer.clear()
                return
            end = start + header.size + length
            if len(buffer) < end:
                break
            self.frame(frame_id, code, bytes(buffer[start + header.size : end]))
            start = end
        if start:
            del buffer[:start]

    def acceptable(self, length: int) -> bool:
        """Whether a frame of ``length`` payload bytes may be read (else the connection goes)."""
        return True

    def frame(self, frame_id: int, code: int, payload: bytes) -> None:
        raise NotImplementedError


class _OwnerSide(_Framed):
    incoming = REQUEST

    def __init__(self, server: RelayServer):
        super().__init__()
        self.server = server

    def acceptable(self, length: int) -> bool:
        if length <= self.server.max_frame:
            return True
        log.error("an ingest process sent a frame of %d bytes (at most %d): closing", length, self.server.max_frame)
        if self.transport is not None:
            self.transport.close()
        return False

    def frame(self, frame_id: int, code: int, payload: bytes) -> None:
        self.server.handle(self, frame_id, code, payload)

    def answer(self, frame_id: int, status: int, payload: bytes) -> None:
        self.send(ANSWER.pack(len(payload), frame_id, status) + payload)


# --- an acceptor's side ---------------------------------------------------------------------


class RelayClient:
    """An acceptor's end: one connection to the owner, many frames in flight
    on it. ``lost`` is set when the owner goes (the acceptor then exits)."""

    def __init__(self) -> None:
        self.lost = asyncio.Event()
        self._side: _AcceptorSide | None = None

    async def connect(self, path: str, timeout: float = 10.0) -> None:
        loop = asyncio.get_running_loop()
        deadline = loop.time() + timeout
        while True:
            try:
                _, side = await loop.create_unix_connection(lambda: _AcceptorSide(self.lost), path=path)
                self._side = side
                return
            except OSError:
                if loop.time() > deadline:
                    raise
                await asyncio.sleep(0.05)

    def close(self) -> None:
        if self._side is not None and self._side.transport is not None:
            self._side.transport.close()

    async def call(self, kind: int, payload: bytes) -> bytes:
        """The owner's answer to one frame; its refusal raised as the same error."""
        side = self._side
        if side is None or side.transport is None or side.transport.is_closing():
            raise Unavailable(_OWNER_GONE)
        status, answer = await side.call(kind, payload)
        if status != OK:
            raise error_of(status, answer)
        return answer

    async def write(self, op: Any) -> None:
        if isinstance(op, AppendSamples):
            await self.call(APPEND, codec.encode(op))
        elif isinstance(op, RecordRejected):
            await self.call(REJECTED, encode_rejected(op))
        else:  # the notify path writes nothing else
            raise TypeError(f"an ingest process relays samples and refusals, not {type(op).__name__}")

    async def values_layout(self, tenant: str, subscription_id: str) -> ValuesLayout | None:
        return layout_of(await self.call(LAYOUT, orjson.dumps([tenant, subscription_id])))

    async def report(self, timings: list[tuple[str, str, int, float]]) -> None:
        """Requests answered here (route, method, status, seconds), for the owner's ``/metrics``."""
        await self.call(TIMINGS, orjson.dumps(timings))


class _AcceptorSide(_Framed):
    incoming = ANSWER

    def __init__(self, lost: asyncio.Event):
        super().__init__()
        self.lost = lost
        self.waiting: dict[int, asyncio.Future] = {}
        self.next_id = 0

    def connection_lost(self, exc) -> None:
        super().connection_lost(exc)
        for future in self.waiting.values():
            if not future.done():
                future.set_exception(Unavailable(_OWNER_GONE))
        self.waiting.clear()
        self.lost.set()

    async def call(self, kind: int, payload: bytes) -> tuple[int, bytes]:
        """Send one frame and await its answer."""
        self.next_id += 1
        future = asyncio.get_running_loop().create_future()
        self.waiting[self.next_id] = future
        self.send(REQUEST.pack(len(payload), self.next_id, kind) + payload)
        return await future

    def frame(self, frame_id: int, code: int, payload: bytes) -> None:
        future = self.waiting.pop(frame_id, None)
        if future is not None and not future.done():
            future.set_result((code, payload))
