"""A real HTTP server on 127.0.0.1 in a thread, for tests that need one to
talk to (a token issuer, a hostile @context host). Subclasses give
``_handler()`` a ``BaseHTTPRequestHandler`` class; use it as a context manager.
"""

from __future__ import annotations

import threading
from http.server import ThreadingHTTPServer

__all__ = ["LocalServer"]


class LocalServer:
    def __init__(self) -> None:
        self._server = ThreadingHTTPServer(("127.0.0.1", 0), self._handler())
        self._server.daemon_threads = True
        self._server.block_on_close = False  # a handler still sending must not hold the test up
        self._thread = threading.Thread(target=self._server.serve_forever, args=(0.05,), daemon=True)

    def _handler(self) -> type:
        raise NotImplementedError

    @property
    def port(self) -> int:
        return self._server.server_address[1]

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}"

    def __enter__(self):
        self._thread.start()
        return self

    def __exit__(self, *_exc) -> None:
        self._server.shutdown()
        self._server.server_close()
