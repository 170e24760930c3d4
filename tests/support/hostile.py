"""A local HTTP server that serves what an attacker would: @context
documents, redirects, bodies that trickle a byte at a time, gzip bombs.
Real sockets on 127.0.0.1, a thread per connection; ``hits`` counts the
requests per path, ``hosts`` the Host headers received.

    with Hostile() as server:
        server.document("/ctx.jsonld", {"@context": {...}})
        server.redirect("/r", "/ctx.jsonld")
        server.slow("/slow", interval=0.5)
        server.gzip_bomb("/bomb", inflated=64 << 20)
        url = server.url + "/ctx.jsonld"
"""

from __future__ import annotations

import contextlib
import json
import threading
import time
import zlib
from http.server import BaseHTTPRequestHandler

from .local_http import LocalServer

__all__ = ["Hostile", "gzip_of_zeros"]


def gzip_of_zeros(size: int) -> bytes:
    """A gzip stream that inflates to ``size`` zero bytes (about 1000:1)."""
    packer = zlib.compressobj(9, zlib.DEFLATED, 16 + zlib.MAX_WBITS)
    chunk = bytes(1 << 20)
    out = []
    for _ in range(size >> 20):
        out.append(packer.compress(chunk))
    out.append(packer.compress(bytes(size & ((1 << 20) - 1))))
    out.append(packer.flush())
    return b"".join(out)


class Hostile(LocalServer):
    def __init__(self):
        self.routes: dict[str, tuple] = {}
        self.hits: dict[str, int] = {}
        self.hosts: list[str] = []
        self._lock = threading.Lock()
        super().__init__()

    def document(self, path: str, doc: object, headers: dict[str, str] | None = None) -> str:
        body = doc if isinstance(doc, bytes) else json.dumps(doc).encode()
        self.routes[path] = ("body", 200, body, {"Content-Type": "application/ld+json", **(headers or {})})
        return self.url + path

    def status(self, path: str, code: int) -> str:
        self.routes[path] = ("body", code, b"{}", {"Content-Type": "application/json"})
        return self.url + path

    def redirect(self, path: str, location: str, code: int = 302) -> str:
        self.routes[path] = ("body", code, b"", {"Location": location})
        return self.url + path

    def slow(self, path: str, interval: float = 0.5, size: int = 10_000) -> str:
        """A valid-looking body sent one byte every ``interval`` seconds."""
        self.routes[path] = ("slow", interval, size)
        return self.url + path

    def gzip_bomb(self, path: str, inflated: int) -> str:
        bomb = gzip_of_zeros(inflated)
        self.routes[path] = ("body", 200, bomb, {"Content-Type": "application/ld+json", "Content-Encoding": "gzip"})
        return self.url + path

    def hit(self, path: str) -> int:
        return self.hits.get(path, 0)

    def _handler(self):
        server = self

        class Handler(BaseHTTPRequestHandler):
            protocol_version = "HTTP/1.1"

            def do_GET(self):
                with server._lock:
                    server.hits[self.path] = server.hits.get(self.path, 0) + 1
                    server.hosts.append(self.headers.get("Host", ""))
                route = server.routes.get(self.path)
                if route is None:
                    self._send(404, b"not here", {"Content-Type": "text/plain"})
                elif route[0] == "body":
                    self._send(route[1], route[2], route[3])
                else:
                    _, interval, size = route
                    self.send_response(200)
                    self.send_header("Content-Type", "application/ld+json")
                    self.send_header("Content-Length", str(size))
                    self.end_headers()
                    with contextlib.suppress(OSError):
                        for _ in range(size):
                            self.wfile.write(b" ")
                            self.wfile.flush()
                            time.sleep(interval)

            def _send(self, code: int, body: bytes, headers: dict[str, str]) -> None:
                self.send_response(code)
                for name, value in headers.items():
                    self.send_header(name, value)
                self.send_header("Content-Length", str(len(body)))
                self.end_headers()
                with contextlib.suppress(OSError):
                    self.wfile.write(body)

            def log_message(self, *args):
                pass

        return Handler
