"""Fixtures for the Grafana tests: one real HTTP server loaded with use-case data.

``grafana_server`` serves ``app_factory(store_url)`` (so the backend is the
suite's: a temporary DuckDB file, or a database of the private PostgreSQL
cluster) with uvicorn on a free localhost port, in a thread of the test
process, and feeds it recorded notifications: a seeded burst of each demo
simulator, as the demo's runner sends them, recorded once with ``python -m
tests.grafana_fixtures`` into ``tests/golden/notifications/grafana/`` (one
gzipped JSON line ``{"headers", "body"}`` per notification). The data is
fixed: every simulated span ends at ``RECORDED_END``, whatever the wall
clock says, so the answers can be compared with golden files.

``grafana_http`` is an HTTP client that compares every 200 JSON answer a
test gets, in order, with ``tests/golden/grafana/<module>.json`` (the same
file for both backends); ``UPDATE_GOLDEN=1`` rewrites those files (review
the diff by hand: they are the specification).

``feed_live`` sends the same bursts through the demo's runner on virtual
time, ending at a given wall-clock moment, for the browser tests whose
pages look at "now".

A plugin of ``tests/conftest.py`` (``pytest_plugins``): every test module can ask for the fixtures.
"""

from __future__ import annotations

import asyncio
import gzip
import json
import os
import threading
import time
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta
from pathlib import Path

import httpx
import pytest
import uvicorn

from tests.support.demo_feed import feed_phases
from tests.support.golden_http import GoldenFile, GoldenHttp, golden_key
from tests.support.server import free_port
from tsdb_service.demo.runner import rng_for
from tsdb_service.usecases import orion
from tsdb_service.usecases.registry import SIMULATORS

ROOT = Path(__file__).resolve().parents[1]
GOLDEN = ROOT / "tests" / "golden"
RECORDED = GOLDEN / "notifications" / "grafana"
UPDATE = os.environ.get("UPDATE_GOLDEN") == "1"
SEED = 5_2024
CONCURRENCY = 16  # per simulator: bigger commit groups, a faster feed
RECORDED_END = datetime(2024, 6, 1, 12, 0, tzinfo=UTC)  # every recorded burst ends here
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
    client: httpx.Client  # keep-alive, shared by the tests of the session

    @property
    def range_ms(self) -> tuple[int, int]:
        """A time range holding every fed sample (simulated spans end at ``fed_at_ms``)."""
        longest = max(speedup * seconds for speedup, seconds in BURSTS.values())
        return self.fed_at_ms - int(longest * 1000) - 60_000, self.fed_at_ms + 60_000


class _ThreadedServer(uvicorn.Server):
    def install_signal_handlers(self) -> None:  # a test thread must not take pytest's signals
        pass


def record() -> dict[str, int]:
    """Write each burst's notifications, exactly as the demo's runner would send
    them for a run ending at ``RECORDED_END``, to ``RECORDED``. Which emissions a
    run sends depends only on the seed, the speedup and the duration
    (``tsdb_service.demo.runner``), so no clock is needed."""
    RECORDED.mkdir(parents=True, exist_ok=True)
    counts = {}
    for name, (speedup, seconds) in BURSTS.items():
        sim = SIMULATORS[name]
        start = RECORDED_END - timedelta(seconds=speedup * seconds)
        physics, wire = rng_for(SEED, sim.name), rng_for(SEED, sim.name, "orion")
        subscription = orion.subscription_id(wire)
        lines = []
        for emission in sim.emissions(start, physics):
            if (emission.at - start).total_seconds() / speedup > seconds:
                break
            headers = orion.notification_headers(sim.tenancy.service, sim.tenancy.service_path, orion.correlator(wire))
            body = orion.notification_body(subscription, emission.entity).decode()
            lines.append(json.dumps({"headers": headers, "body": body}, separators=(",", ":")))
        (RECORDED / f"{name}.jsonl.gz").write_bytes(gzip.compress(("\n".join(lines) + "\n").encode(), mtime=0))
        counts[name] = len(lines)
    return counts


def recorded() -> dict[str, list[tuple[dict, bytes]]]:
    """The recorded notifications per burst, in sending order."""
    out = {}
    for name in BURSTS:
        text = gzip.decompress((RECORDED / f"{name}.jsonl.gz").read_bytes()).decode()
        notes = [json.loads(line) for line in text.splitlines()]
        out[name] = [(note["headers"], note["body"].encode()) for note in notes]
    return out


async def _post_all(url: str, notes: list[tuple[dict, bytes]]) -> int:
    """POST every notification over CONCURRENCY keep-alive connections; returns
    how many were acknowledged. Each (entity, time index) occurs once, so the
    stored data does not depend on the order in which they arrive.

    Plain HTTP/1.1 on asyncio streams: the server runs in this process, and
    an HTTP client library's own work (about 0.7 ms a request with httpx)
    would take the interpreter from it for as long as the server's."""
    host, port = httpx.URL(url).host, httpx.URL(url).port
    queue = list(reversed(notes))
    acked = 0

    async def sender() -> None:
        nonlocal acked
        reader, writer = await asyncio.open_connection(host, port)
        try:
            while queue:
                headers, body = queue.pop()
                fields = {"Host": f"{host}:{port}", **headers, "Content-Length": str(len(body))}
                head = "POST /v2/notify HTTP/1.1\r\n" + "".join(f"{k}: {v}\r\n" for k, v in fields.items())
                writer.write(head.encode("latin-1") + b"\r\n" + body)
                status = await reader.readline()
                length = 0
                while (line := await reader.readline()) not in (b"\r\n", b""):
                    name, _, value = line.partition(b":")
                    if name.strip().lower() == b"content-length":
                        length = int(value)
                answer = await reader.readexactly(length)
                assert status.split(b" ", 2)[1] == b"200", status + answer
                acked += 1
        finally:
            writer.close()
            await writer.wait_closed()

    await asyncio.gather(*(sender() for _ in range(CONCURRENCY)))
    return acked


async def _feed_recorded(url: str) -> dict[str, int]:
    notes = recorded()
    counts = await asyncio.gather(*(_post_all(url, notes[name]) for name in BURSTS))
    return dict(zip(BURSTS, counts, strict=True))


async def feed_live(url: str, end_ms: int) -> dict:
    """Every burst through the demo's runner, each on its own virtual clock
    (no waiting: the bursts' wall durations are tiny anyway); each simulated
    span ends at ``end_ms``."""
    end = datetime.fromtimestamp(end_ms / 1000, tz=UTC)
    return await feed_phases(url, BURSTS, seed=SEED, end=end, concurrency=CONCURRENCY)


def _start(app_factory, store_url_factory) -> tuple[LoadedService, _ThreadedServer, threading.Thread]:
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
        stats = asyncio.run(_feed_recorded(url))
        assert all(count > 1000 for count in stats.values()), stats
    except BaseException:
        _stop(server, thread)
        raise
    client = httpx.Client(base_url=url, timeout=30.0)
    return LoadedService(url, stats, int(RECORDED_END.timestamp() * 1000), client), server, thread


def _stop(server: _ThreadedServer, thread: threading.Thread) -> None:
    server.should_exit = True
    thread.join(timeout=30)


@pytest.fixture(scope="session")
def grafana_server(app_factory, store_url_factory):
    """One loaded server per backend for the whole session (this module is a
    plugin of ``tests/conftest.py``: one fixture definition for every module)."""
    service, server, thread = _start(app_factory, store_url_factory)
    try:
        yield service
    finally:
        service.client.close()
        _stop(server, thread)


_GOLDEN_FILES: dict[str, GoldenFile] = {}


@pytest.fixture
def grafana_http(grafana_server, request):
    """The loaded server's client, checking each 200 JSON answer against the golden file."""
    module = Path(request.node.path).stem.removeprefix("test_")
    if module not in _GOLDEN_FILES:
        _GOLDEN_FILES[module] = GoldenFile(GOLDEN / "grafana" / f"{module}.json", UPDATE)
    http = GoldenHttp(grafana_server.client, _GOLDEN_FILES[module], golden_key(request.node.name))
    yield http
    http.finish()
    _GOLDEN_FILES[module].save()  # update mode only


def panels_of(doc: dict) -> list[dict]:
    """Every panel of a dashboard, rows included (collapsed rows hold their panels)."""
    out = []
    for panel in doc.get("panels", []):
        out.append(panel)
        out.extend(panel.get("panels", []))
    return out


if __name__ == "__main__":
    print(record())
