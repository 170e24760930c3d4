"""An ASGI app served by uvicorn on a free 127.0.0.1 port, in a thread, for
tests that need a real HTTP peer (a stand-in broker, tsdb-service itself).

    with serving(app) as url:
        httpx.get(url + "/v2")
"""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager

import uvicorn

from tests.support.server import free_port

__all__ = ["serving"]


class _Server(uvicorn.Server):
    def install_signal_handlers(self) -> None:  # a test thread must not take pytest's signals
        pass


@contextmanager
def serving(app) -> Iterator[str]:
    """``app`` on a free 127.0.0.1 port with uvicorn, in a thread; yields its URL."""
    port = free_port()
    server = _Server(uvicorn.Config(app, host="127.0.0.1", port=port, log_level="warning", lifespan="on"))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    deadline = time.monotonic() + 30
    while not server.started:
        if not thread.is_alive() or time.monotonic() > deadline:
            raise RuntimeError("the test server did not start")
        time.sleep(0.02)
    try:
        yield f"http://127.0.0.1:{port}"
    finally:
        server.should_exit = True
        thread.join(timeout=30)
