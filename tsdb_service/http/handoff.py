"""Connections an acceptor process hands to the serving process (``--ingest-processes``).

The kernel gives each new connection on the shared port to any of our
processes (``SO_REUSEPORT``). An acceptor serves notifications only; the
first request of any other kind on one of its connections (a history read,
the explorer, Grafana) makes it hand the whole connection to the serving
process, which owns the database: the socket itself goes over a Unix socket
(``SCM_RIGHTS``) with the bytes of that request read so far, and the owner
serves the connection from then on as if it had accepted it. A client sees
one service; a read pays nothing after its connection's first request, and
the acceptor never parses or copies what it hands over.

Invariants:

* **Only at a request's first byte.** A connection is handed over only when
  nothing of it is in flight in the acceptor: the previous request complete,
  its answer written and flushed to the kernel, no request pipelined behind
  it. Otherwise the request is served where it is (``ingest.acceptor``
  passes it to the owner over HTTP).
* **Bytes in order.** The owner's protocol sees the handed bytes before
  anything it reads from the socket itself; the acceptor reads nothing more
  from the socket once it decided (reading paused, then its descriptor
  closed, which leaves the connection open: the owner holds another).
* **The same limits.** The owner's protocol is the one it serves its own
  connections with (``http.server.GuardedHttpToolsProtocol``): header and
  body deadlines, the head size limit, the connection cap.
* **Only ours can hand over.** The socket lives in the private directory
  ``serve`` made (mode 0700), itself mode 0600.

Failure modes: the owner is not listening yet, or the hand-over socket
fails: the acceptor serves the request itself (passing it on over HTTP),
nothing is lost. The owner gets a descriptor it cannot use: it closes it
(the client sees the connection close, as with any restart).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import socket
from collections.abc import Callable

from tsdb_service.http.server import GuardedHttpToolsProtocol

log = logging.getLogger("tsdb_service.http")

MAX_HANDED_BYTES = 64 * 1024  # a request's first bytes that travel with its socket; past it, no hand-over
_SEND_TIMEOUT_S = 0.5


def request_path(head: bytes) -> bytes | None:
    """The path of the request line at the start of ``head`` (no query), or
    None while the request line's target is not complete."""
    first = head.find(b" ")
    if first < 0:
        return None
    end = head.find(b" ", first + 1)
    if end < 0:
        return None
    return head[first + 1 : end].split(b"?", 1)[0]


# --- the acceptor's side ------------------------------------------------------------------


class HandOver:
    """An acceptor's end of the hand-over socket, connected on first use."""

    def __init__(self, path: str):
        self.path = path
        self._sock: socket.socket | None = None

    def give(self, fd: int, head: bytes) -> bool:
        """Send the connection ``fd`` with its first bytes ``head``; False
        when it cannot (then the caller keeps the connection)."""
        try:
            if self._sock is None:
                sock = socket.socket(socket.AF_UNIX, socket.SOCK_SEQPACKET)
                sock.settimeout(_SEND_TIMEOUT_S)
                sock.connect(self.path)
                self._sock = sock
            socket.send_fds(self._sock, [head], [fd])
        except OSError as exc:
            log.debug("could not hand a connection to the serving process: %s", exc)
            self.close()
            return False
        return True

    def close(self) -> None:
        if self._sock is not None:
            with contextlib.suppress(OSError):
                self._sock.close()
            self._sock = None


def handing_over(keep: frozenset[bytes], hand_over: HandOver) -> type[GuardedHttpToolsProtocol]:
    """The acceptor's protocol: requests for a path in ``keep`` are served
    here; at the first other one, the connection goes to the owner."""

    class HandingOverProtocol(GuardedHttpToolsProtocol):
        _undecided = b""  # the start of a request whose target is not complete yet

        def data_received(self, data: bytes) -> None:
            if self._undecided or self._at_request_start():
                head = self._undecided + data
                path = request_path(head)
                if path is None and len(head) < MAX_HANDED_BYTES:
                    self._undecided = head  # too little to decide
                    return
                self._undecided = b""
                if path is not None and path not in keep and self._hand_over(head):
                    return
                data = head
            super().data_received(data)

        def _at_request_start(self) -> bool:
            cycle = self.cycle
            return (
                self._in_head
                and self._head_bytes == 0
                and not self.pipeline
                and (cycle is None or cycle.response_complete)
                and self.transport.get_write_buffer_size() == 0
            )

        def _hand_over(self, head: bytes) -> bool:
            if len(head) > MAX_HANDED_BYTES:
                return False
            sock = self.transport.get_extra_info("socket")
            if sock is None:
                return False
            self.transport.pause_reading()
            if not hand_over.give(sock.fileno(), head):
                self.transport.resume_reading()
                return False
            self.transport.abort()  # our descriptor only: the owner holds the connection now
            return True

    return HandingOverProtocol


# --- the owner's side -----------------------------------------------------------------------


class Adopter:
    """The owner's end: takes connections (and their first bytes) from the
    acceptors and serves each with ``make_protocol`` (uvicorn's factory for
    ``GuardedHttpToolsProtocol``)."""

    def __init__(self, path: str, make_protocol: Callable[[], asyncio.Protocol]):
        self.path = path
        self.make_protocol = make_protocol
        self._listener: socket.socket | None = None
        self._peers: list[socket.socket] = []
        self._closed = False

    def start(self) -> None:
        listener = socket.socket(socket.AF_UNIX, socket.SOCK_SEQPACKET)
        listener.bind(self.path)
        os.chmod(self.path, 0o600)
        listener.listen(64)
        listener.setblocking(False)
        self._listener = listener
        asyncio.get_running_loop().add_reader(listener.fileno(), self._accept)

    def close(self) -> None:
        self._closed = True
        loop = asyncio.get_running_loop()
        for sock in [*self._peers, *([self._listener] if self._listener else [])]:
            with contextlib.suppress(Exception):
                loop.remove_reader(sock.fileno())
            sock.close()
        self._peers.clear()
        self._listener = None

    def _accept(self) -> None:
        assert self._listener is not None
        try:
            peer, _ = self._listener.accept()
        except OSError:
            return
        peer.setblocking(False)
        self._peers.append(peer)
        asyncio.get_running_loop().add_reader(peer.fileno(), self._receive, peer)

    def _receive(self, peer: socket.socket) -> None:
        try:
            head, fds, _, _ = socket.recv_fds(peer, MAX_HANDED_BYTES + 1024, 4)
        except BlockingIOError:
            return
        except OSError:
            head, fds = b"", []
        if not head and not fds:  # the acceptor is gone
            asyncio.get_running_loop().remove_reader(peer.fileno())
            self._peers.remove(peer)
            peer.close()
            return
        for extra in fds[1:]:  # one connection per message; never leak a descriptor
            socket.close(extra)
        if fds:
            self._adopt(fds[0], head)

    def _adopt(self, fd: int, head: bytes) -> None:
        if self._closed:
            socket.close(fd)
            return
        try:
            sock = socket.socket(fileno=fd)
            sock.setblocking(False)
        except OSError as exc:
            log.warning("a connection handed over by an ingest process could not be used: %s", exc)
            socket.close(fd)
            return
        make = self.make_protocol

        def protocol() -> asyncio.Protocol:
            made = make()
            assert isinstance(made, GuardedHttpToolsProtocol)
            made.first_bytes(head)
            return made

        asyncio.get_running_loop().create_task(_serve(sock, protocol))


async def _serve(sock: socket.socket, protocol: Callable[[], asyncio.Protocol]) -> None:
    try:
        await asyncio.get_running_loop().connect_accepted_socket(protocol, sock)
    except OSError as exc:
        log.debug("a handed-over connection closed before it was served: %s", exc)
        sock.close()
