"""Fixtures for the Grafana tests: one real HTTP server loaded with use-case data.

``grafana_server`` serves ``app_factory(store_url)`` (so the backend is the
suite's: a temporary DuckDB file today, PostgreSQL when the lead parametrizes
``store_url_factory``) with uvicorn on a free localhost port, in a thread of
the test process, and feeds it a short seeded burst of each demo simulator
through the demo's own runner: real Orion notifications over real HTTP.

Each burst is bounded in *simulated* time (``speedup x duration``), so the
data depends only on the seed. The simulated spans end at the moment the
feed starts; ``LoadedService.range_ms`` covers them all.

Import with ``from tests.grafana_fixtures import grafana_http, grafana_server  # noqa: F401``.
"""

from __future__ import annotations

import asyncio
import threading
import time
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta
from pathlib import Path

import httpx
import pytest
import uvicorn

from tests.support.server import free_port
from tsdb_service.demo.runner import RunConfig, run
from tsdb_service.demo.usecases import SIMULATORS

ROOT = Path(__file__).resolve().parents[1]
SEED = 5_2024
CONCURRENCY = 16  # per simulator: bigger commit groups, a faster feed
# name -> (speedup, wall duration): simulated seconds = speedup x duration.
BURSTS = {
    "lawnmower": (20_000.0, 0.06),  # 20 simulated minutes: a mowing cycle or two
    "warehouse": (20_000.0, 0.018),  # 6 minutes: several door passes
    "drone": (200_000.0, 0.036),  # 2 hours: some 25 missions
}


@dataclass
class LoadedService:
    url: str
    stats: dict
    fed_at_ms: int

    @property
    def range_ms(self) -> tuple[int, int]:
        """A time range holding every fed sample (simulated spans end at ``fed_at_ms``)."""
        longest = max(speedup * seconds for speedup, seconds in BURSTS.values())
        return self.fed_at_ms - int(longest * 1000) - 60_000, self.fed_at_ms + 60_000


class _ThreadedServer(uvicorn.Server):
    def install_signal_handlers(self) -> None:  # a test thread must not take pytest's signals
        pass


async def _feed(url: str, end_ms: int) -> dict:
    """Every burst's simulated span ends at ``end_ms``."""
    end = datetime.fromtimestamp(end_ms / 1000, tz=UTC)
    runs = [
        run(
            [SIMULATORS[name]],
            RunConfig(
                url,
                speedup=speedup,
                duration=seconds,
                seed=SEED,
                concurrency=CONCURRENCY,
                start=end - timedelta(seconds=speedup * seconds),
            ),
        )
        for name, (speedup, seconds) in BURSTS.items()
    ]
    stats = {}
    for result in await asyncio.gather(*runs):
        stats.update(result)
    return stats


@dataclass
class _Running:
    service: LoadedService
    server: _ThreadedServer
    thread: threading.Thread
    users: int = 0


# One loaded server per backend for the whole session. Each test module that
# imports ``grafana_server`` gets its own (session-scoped) fixture definition,
# so the servers are shared here, keyed by the backend's store-URL factory,
# and each is stopped when its last user is done.
_RUNNING: dict[int, _Running] = {}


def _start(app_factory, store_url_factory) -> _Running:
    app = app_factory(store_url_factory("grafana"))
    port = free_port()
    server = _ThreadedServer(uvicorn.Config(app, host="127.0.0.1", port=port, log_level="warning", lifespan="on"))
    thread = threading.Thread(target=server.run, name="grafana-test-server", daemon=True)
    thread.start()
    try:
        deadline = time.monotonic() + 30
        while not server.started:
            if not thread.is_alive() or time.monotonic() > deadline:
                raise RuntimeError("the test server did not start")
            time.sleep(0.02)
        url = f"http://127.0.0.1:{port}"
        fed_at = int(time.time() * 1000)
        stats = asyncio.run(_feed(url, fed_at))
        for name, row in stats.items():
            assert row.sent > 100 and row.failed == 0, f"{name}: {row}"
    except BaseException:
        _stop(server, thread)
        raise
    return _Running(LoadedService(url, stats, fed_at), server, thread)


def _stop(server: _ThreadedServer, thread: threading.Thread) -> None:
    server.should_exit = True
    thread.join(timeout=30)


@pytest.fixture(scope="session")
def grafana_server(app_factory, store_url_factory):
    key = id(store_url_factory)
    running = _RUNNING.get(key)
    if running is None:
        running = _RUNNING[key] = _start(app_factory, store_url_factory)
    running.users += 1
    try:
        yield running.service
    finally:
        running.users -= 1
        if running.users == 0:
            del _RUNNING[key]
            _stop(running.server, running.thread)


@pytest.fixture(scope="session")
def grafana_http(grafana_server):
    with httpx.Client(base_url=grafana_server.url, timeout=30.0) as client:
        yield client


def panels_of(doc: dict) -> list[dict]:
    """Every panel of a dashboard, rows included (collapsed rows hold their panels)."""
    out = []
    for panel in doc.get("panels", []):
        out.append(panel)
        out.extend(panel.get("panels", []))
    return out
