"""The HTTP server's defences against slow and idle clients.

uvicorn (0.54, httptools) never times out a request whose headers or body
never finish: 20,000 half-open sockets exhausted the descriptor limit, and
from then on every normal request failed. Its ``timeout_keep_alive`` only
covers the idle time *between* requests, and ``limit_concurrency`` answers
503 to new requests but keeps every connection open. So the protocol here
adds, per connection:

* a **header deadline**: a connection that has not completed a request's
  headers ``header_timeout_s`` after it opened (or after that request's first
  byte) is closed;
* a **body deadline**: a request body not complete ``body_timeout_s`` after
  its headers is cut off; the route sees a disconnect (the notify route logs
  it as one line, nothing is stored);
* a **connection cap**: past ``max_connections`` open connections a new one
  is answered 503 and closed at once, so descriptors stay free for the
  process's own files and for clients once the cap eases;
* a **head size limit**: a request line and header fields of more than
  ``max_header_bytes`` are answered 431 and the connection closed. httptools
  keeps a header it has not finished in memory (and copies it as it grows:
  six parallel 40 MB headers cost 330 MB and stalled every request for
  seconds), so the bytes are counted as they arrive, before the parser
  sees them, and the complete head is measured once more;

and at start the soft descriptor limit is raised to the hard one. Settings:
``TSDB_HEADER_TIMEOUT_S``, ``TSDB_BODY_TIMEOUT_S``, ``TSDB_MAX_CONNECTIONS``,
``TSDB_KEEP_ALIVE_S``, ``TSDB_MAX_HEADER_BYTES``; ``cli serve`` passes them
to the worker processes through the environment, where this module reads
them once.
"""

from __future__ import annotations

import logging
from asyncio import TimerHandle, Transport
from functools import cache
from typing import cast

from uvicorn.protocols.http.httptools_impl import HttpToolsProtocol

from tsdb_service.core.config import Settings

log = logging.getLogger("tsdb_service.http")

_BUSY_BODY = b'{"error":"ServiceUnavailable","description":"too many connections; try again later"}'
_BUSY = (
    b"HTTP/1.1 503 Service Unavailable\r\ncontent-type: application/json\r\nconnection: close\r\n"
    b"content-length: %d\r\n\r\n%s" % (len(_BUSY_BODY), _BUSY_BODY)
)
_HEAD_BODY = (
    b'{"error":"RequestHeaderFieldsTooLarge","description":"the request line and headers are larger than '
    b'the service accepts (TSDB_MAX_HEADER_BYTES)"}'
)
_HEAD_TOO_LARGE = (
    b"HTTP/1.1 431 Request Header Fields Too Large\r\ncontent-type: application/json\r\n"
    b"connection: close\r\ncontent-length: %d\r\n\r\n%s" % (len(_HEAD_BODY), _HEAD_BODY)
)
_END_OF_HEAD = b"\r\n\r\n"


@cache
def _limits() -> tuple[float, float, int, int]:
    settings = Settings()
    return settings.header_timeout_s, settings.body_timeout_s, settings.max_connections, settings.max_header_bytes


class GuardedHttpToolsProtocol(HttpToolsProtocol):
    """uvicorn's httptools protocol with header and body deadlines and a
    connection cap (see the module docstring)."""

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self._header_timeout, self._body_timeout, self._max_connections, self._max_head = _limits()
        self._deadline: TimerHandle | None = None
        self._in_head = True  # the bytes arriving belong to a request head
        self._head_bytes = 0
        self._tail = b""  # the last bytes seen, in case the head's end is split between reads
        self._refused = False
        self._first = b""  # bytes of this connection another process read (first_bytes)

    def first_bytes(self, data: bytes) -> None:
        """Serve ``data`` before anything read from the socket: the bytes an
        acceptor read of this connection before it handed it over
        (``http.handoff``)."""
        self._first = data

    def _feed_first(self) -> None:
        if self._first and not self.transport.is_closing():
            data, self._first = self._first, b""
            self.data_received(data)

    def data_received(self, data: bytes) -> None:
        if self._first:  # handed-over bytes first, whatever the socket brought since
            data, self._first = self._first + data, b""
        if self._refused:
            return
        if self._in_head:
            seen = self._tail + data
            end = seen.find(_END_OF_HEAD)
            self._head_bytes += len(data) if end < 0 else max(0, end + len(_END_OF_HEAD) - len(self._tail))
            if self._head_bytes > self._max_head:
                self._refuse_head()
                return
            self._tail = seen[-(len(_END_OF_HEAD) - 1) :]
        super().data_received(data)
        if self._refused:
            self._refuse_head()

    def _refuse_head(self) -> None:
        self._refused = True
        self._disarm()
        if not self.transport.is_closing():
            log.info(
                "request head from %s over %d bytes (TSDB_MAX_HEADER_BYTES): 431", _peer(self.client), self._max_head
            )
            self.transport.write(_HEAD_TOO_LARGE)
            self.transport.close()

    def connection_made(self, transport) -> None:
        super().connection_made(cast(Transport, CoalescingTransport(transport, self.loop)))
        if len(self.connections) > self._max_connections:
            log.warning(
                "%d connections open (TSDB_MAX_CONNECTIONS): refusing %s", len(self.connections) - 1, _peer(self.client)
            )
            transport.write(_BUSY)
            transport.close()
            return
        self._arm(self._header_timeout, "headers")
        if self._first:
            self.loop.call_soon(self._feed_first)

    def connection_lost(self, exc) -> None:
        self._disarm()
        super().connection_lost(exc)

    def on_message_begin(self) -> None:
        super().on_message_begin()
        if self._deadline is None:  # a further request on a kept-alive connection
            self._arm(self._header_timeout, "headers")

    def on_headers_complete(self) -> None:
        self._disarm()
        self._in_head = False
        if len(self.url) + sum(len(name) + len(value) + 4 for name, value in self.headers) > self._max_head:
            self._refused = True  # answered once the parser returns (data_received); the app never starts
            return
        super().on_headers_complete()
        self._arm(self._body_timeout, "body")

    def on_body(self, body: bytes) -> None:
        if not self._refused:
            super().on_body(body)

    def on_message_complete(self) -> None:
        self._disarm()
        if self._refused:
            return
        super().on_message_complete()
        self._in_head, self._head_bytes, self._tail = True, 0, b""

    def _arm(self, seconds: float, what: str) -> None:
        self._disarm()
        self._deadline = self.loop.call_later(seconds, self._expire, what)

    def _disarm(self) -> None:
        if self._deadline is not None:
            self._deadline.cancel()
            self._deadline = None

    def _expire(self, what: str) -> None:
        self._deadline = None
        if not self.transport.is_closing():
            log.debug(
                "closing %s: request %s incomplete after the timeout (TSDB_%s_TIMEOUT_S)",
                _peer(self.client),
                what,
                "HEADER" if what == "headers" else "BODY",
            )
            self.transport.close()


class CoalescingTransport:
    """A transport whose writes made during one turn of the event loop leave
    as one: uvicorn writes an answer's status line and headers, then its
    body, and each write was a ``send`` system call of its own, made with
    the interpreter lock held (about a tenth of the lock's time at 64
    connections of notifications). Everything else is the transport's own;
    ``close`` sends what is pending first, ``abort`` drops it, and the
    write buffer's size counts it."""

    __slots__ = ("_loop", "_pending", "_scheduled", "_transport")

    def __init__(self, transport, loop):
        self._transport = transport
        self._loop = loop
        self._pending: list[bytes] = []
        self._scheduled = False

    def write(self, data: bytes) -> None:
        self._pending.append(data)
        if not self._scheduled:
            self._scheduled = True
            self._loop.call_soon(self._flush)

    def _flush(self) -> None:
        self._scheduled = False
        if self._pending:
            data = self._pending[0] if len(self._pending) == 1 else b"".join(self._pending)
            self._pending.clear()
            if not self._transport.is_closing():
                self._transport.write(data)

    def close(self) -> None:
        self._flush()
        self._transport.close()

    def abort(self) -> None:
        self._pending.clear()
        self._transport.abort()

    def get_write_buffer_size(self) -> int:
        return self._transport.get_write_buffer_size() + sum(len(data) for data in self._pending)

    def __getattr__(self, name: str):
        return getattr(self._transport, name)


def _peer(client) -> str:
    return f"{client[0]}:{client[1]:d}" if client else "a client"


def raise_fd_limit() -> tuple[int, int] | None:
    """Soft descriptor limit up to the hard one (each connection holds one);
    returns (soft, hard) as now set, or None where there is no such limit."""
    try:
        import resource
    except ImportError:  # pragma: no cover - not POSIX
        return None
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    if soft != hard:
        try:
            resource.setrlimit(resource.RLIMIT_NOFILE, (hard, hard))
            soft = hard
        except (ValueError, OSError) as exc:
            log.warning("could not raise the open-files limit from %d to %d: %s", soft, hard, exc)
    return soft, hard


def check_bind(host: str, port: int) -> None:
    """``ValueError`` saying why the server could not listen on ``host:port``
    (an unknown name, an address of another machine, a port in use or
    reserved); checked by ``serve`` before it creates the database, with
    ``SO_REUSEADDR`` as uvicorn binds. The socket is closed at once, so
    another program can still take the port before uvicorn does: then
    uvicorn reports it."""
    import errno
    import socket

    try:
        addresses = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)
    except (socket.gaierror, UnicodeError) as exc:
        reason = exc.strerror if isinstance(exc, socket.gaierror) else str(exc)
        raise ValueError(f"--host (TSDB_HOST): cannot listen on {host!r}: {reason}") from None
    family, kind, proto, _, address = addresses[0]
    with socket.socket(family, kind, proto) as sock:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            sock.bind(address)
        except OSError as exc:
            where = f"{host}:{port}"
            if exc.errno == errno.EADDRINUSE:
                reason = (
                    f"--port (TSDB_PORT): {where} is already in use: stop what listens there, or choose another --port"
                )
            elif exc.errno == errno.EADDRNOTAVAIL:
                reason = f"--host (TSDB_HOST): {host} is not an address of this machine (0.0.0.0 listens on all)"
            elif exc.errno == errno.EACCES:
                reason = f"--port (TSDB_PORT): no permission to listen on {where} (ports below 1024 need privileges)"
            else:
                reason = f"--host/--port: cannot listen on {where}: {exc.strerror or exc}"
            raise ValueError(reason) from None


def log_config(level: str) -> dict:
    """uvicorn's logging configuration, with tsdb-service's own loggers
    printed the same way at ``level`` (the database opened, warnings)."""
    import copy

    from uvicorn.config import LOGGING_CONFIG

    config = copy.deepcopy(LOGGING_CONFIG)
    config["loggers"]["tsdb_service"] = {"handlers": ["default"], "level": level.upper(), "propagate": False}
    return config


def listening_sockets(host: str, port: int, count: int) -> list:
    """``count`` listening TCP sockets on the same ``host:port`` for
    ``serve --ingest-processes`` (the first for the serving process, one per
    acceptor, handed to it): ``SO_REUSEPORT`` lets the kernel spread new
    connections evenly over them. They are bound one after the other, right
    after ``serve`` checked that nothing holds the port (``check_bind``,
    without ``SO_REUSEPORT``, so a second service started on the port is
    refused); an acceptor that dies leaves its socket with the serving
    process, whose queue waits for the acceptor started again."""
    import socket

    family, kind, proto, _, address = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)[
        0
    ]
    sockets = []
    for _ in range(count):
        sock = socket.socket(family, kind, proto)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEPORT, 1)
        if family == socket.AF_INET6:
            sock.setsockopt(socket.IPPROTO_IPV6, socket.IPV6_V6ONLY, 0)
        sock.bind(address)
        sock.listen(2048)
        sockets.append(sock)
    return sockets


def private_socket(path: str):
    """A listening Unix socket at ``path`` that only this user may connect to."""
    import os
    import socket

    sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    sock.bind(path)
    os.chmod(path, 0o600)
    sock.listen(2048)
    return sock
