"""Replay the simulators against a service as Orion would, with a progress display.

Time: a simulator's instants are mapped to wall-clock time as
``(at - sim_start) / speedup``. With ``--duration D`` the simulated span is
``D * speedup`` and ends now (``sim_start = now - D * speedup``), so a fast
replay lands on a realistic, recent time axis. Which emissions are sent
depends only on the seed, the speedup and the duration, never on how fast
the service answers: a slow service makes the run late, not different.

HTTP: ``concurrency`` sender tasks, each one keep-alive ``httpx.AsyncClient``
connection, fed by a small bounded queue: at most that many requests are in
flight, the way a broker's notification worker pool behaves. A non-2xx
answer or a transport error counts as failed; Orion would not retry it.
"""

from __future__ import annotations

import asyncio
import importlib.util
import random
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime, timedelta
from typing import TextIO

import httpx

from . import orion
from .base import Simulator


def _cache_missing_sniffio() -> None:
    """httpcore runs ``import sniffio`` on every async request. Without sniffio
    installed (anyio 4 no longer needs it) each failing import walks sys.path,
    about 0.2 ms a request; a ``None`` entry makes the miss instant."""
    if "sniffio" not in sys.modules and importlib.util.find_spec("sniffio") is None:
        sys.modules["sniffio"] = None  # type: ignore[assignment]


_cache_missing_sniffio()


@dataclass
class Stats:
    """What one simulator has done so far: the progress display's row."""

    name: str
    sent: int = 0
    acked: int = 0
    failed: int = 0
    last_error: str | None = None
    sim_time: datetime | None = None
    done: bool = False


@dataclass(frozen=True)
class RunConfig:
    url: str
    speedup: float = 1.0
    duration: float | None = None  # wall seconds; None runs until stopped
    seed: int = 0
    concurrency: int = 16
    start: datetime | None = None  # simulated start; default per the module docstring


@dataclass
class _Clock:
    sim_start: datetime
    speedup: float
    wall_start: float = field(default_factory=time.monotonic)

    def due(self, at: datetime) -> float:
        """Wall seconds after the start at which ``at`` is to be sent."""
        return (at - self.sim_start).total_seconds() / self.speedup

    def elapsed(self) -> float:
        return time.monotonic() - self.wall_start


def default_start(speedup: float, duration: float | None, now: datetime | None = None) -> datetime:
    """A bounded run ends now; an open-ended one starts now. Rounded to the millisecond."""
    now = now or datetime.now(UTC)
    start = now - timedelta(seconds=duration * speedup) if duration else now
    return start.replace(microsecond=start.microsecond // 1000 * 1000)


def rng_for(seed: int, name: str, purpose: str = "physics") -> random.Random:
    """An independent stream per simulator and purpose, so adding one never shifts another."""
    return random.Random(f"{seed}:{name}:{purpose}")


async def run(
    simulators: Sequence[Simulator],
    config: RunConfig,
    *,
    progress: Progress | None = None,
    stop: asyncio.Event | None = None,
) -> dict[str, Stats]:
    """Send every simulator's notifications until the duration ends or ``stop`` is set."""
    if config.speedup <= 0 or config.concurrency < 1:
        raise ValueError("speedup and concurrency must be positive")
    stop = stop or asyncio.Event()
    clock = _Clock(config.start or default_start(config.speedup, config.duration), config.speedup)
    stats = {sim.name: Stats(sim.name) for sim in simulators}
    outbox: asyncio.Queue = asyncio.Queue(maxsize=2 * config.concurrency)
    senders = [asyncio.create_task(_sender(config.url, outbox)) for _ in range(config.concurrency)]
    reporter = asyncio.create_task(progress.follow(stats, clock)) if progress else None
    try:
        await asyncio.gather(*(_drive(sim, clock, config, stats[sim.name], outbox, stop) for sim in simulators))
    finally:
        for _ in senders:
            await outbox.put(None)
        await asyncio.gather(*senders, return_exceptions=True)
        if reporter:
            reporter.cancel()
            await asyncio.gather(reporter, return_exceptions=True)
            progress.final(stats, clock)
    return stats


async def _drive(sim, clock, config, stats: Stats, outbox: asyncio.Queue, stop: asyncio.Event) -> None:
    """Pace one simulator's emissions onto the wall clock and queue them for the senders."""
    physics, wire = rng_for(config.seed, sim.name), rng_for(config.seed, sim.name, "orion")
    subscription = orion.subscription_id(wire)
    for emission in sim.emissions(clock.sim_start, physics):
        due = clock.due(emission.at)
        if config.duration is not None and due > config.duration:
            break
        if await _wait_or_stop(stop, due - clock.elapsed()):
            break
        headers = orion.notification_headers(sim.tenancy.service, sim.tenancy.service_path, orion.correlator(wire))
        body = orion.notification_body(subscription, emission.entity)
        await outbox.put((stats, headers, body))  # blocks while every sender is busy: backpressure
        stats.sent += 1
        stats.sim_time = emission.at
    stats.done = True


async def _wait_or_stop(stop: asyncio.Event, seconds: float) -> bool:
    """Sleep until an emission is due; True if the run was stopped meanwhile."""
    if stop.is_set():
        return True
    if seconds <= 0:
        await asyncio.sleep(0)  # let the senders and the display run while catching up
        return stop.is_set()
    try:
        await asyncio.wait_for(stop.wait(), timeout=seconds)
    except TimeoutError:
        return False
    return True


async def _sender(url: str, outbox: asyncio.Queue) -> None:
    """One keep-alive connection posting queued notifications until it gets ``None``.

    A client per connection rather than one shared pool: httpcore's pool
    scans every connection on every request, which doubles the client's cost
    per notification at 16 connections.
    """
    limits = httpx.Limits(max_connections=1, max_keepalive_connections=1)
    async with httpx.AsyncClient(base_url=url, timeout=30.0, limits=limits) as client:
        while (item := await outbox.get()) is not None:
            await _post(client, *item)


async def _post(client: httpx.AsyncClient, stats: Stats, headers: dict, body: bytes) -> None:
    try:
        response = await client.post("/v2/notify", content=body, headers=headers)
        if 200 <= response.status_code < 300:
            stats.acked += 1
        else:
            stats.failed += 1
            stats.last_error = f"HTTP {response.status_code}: {response.text[:200]}"
    except httpx.HTTPError as exc:
        stats.failed += 1
        stats.last_error = f"{type(exc).__name__}: {exc}"


class Progress:
    """Sent / acknowledged / failed per simulator: redrawn in place on a terminal,
    a line every ``interval`` seconds otherwise (logs, CI)."""

    def __init__(self, stream: TextIO | None = None, interval: float | None = None):
        self.stream = stream or sys.stdout
        self.tty = self.stream.isatty()
        self.interval = interval or (0.5 if self.tty else 10.0)
        self._drawn = 0

    async def follow(self, stats: dict[str, Stats], clock: _Clock) -> None:
        while True:
            await asyncio.sleep(self.interval)
            self._draw(stats, clock)

    def final(self, stats: dict[str, Stats], clock: _Clock) -> None:
        self._draw(stats, clock)
        for row in stats.values():
            if row.last_error:
                self.stream.write(f"  {row.name}: last failure: {row.last_error}\n")
        self.stream.flush()

    def _draw(self, stats: dict[str, Stats], clock: _Clock) -> None:
        lines = [self.line(row) for row in stats.values()]
        lines.append(f"  elapsed {clock.elapsed():7.1f} s   speedup x{clock.speedup:g}")
        if self.tty:
            if self._drawn:
                self.stream.write(f"\x1b[{self._drawn}F")
            self.stream.write("".join(f"{line}\x1b[K\n" for line in lines))
            self._drawn = len(lines)
        else:
            self.stream.write("\n".join(lines) + "\n")
        self.stream.flush()

    @staticmethod
    def line(row: Stats) -> str:
        when = orion.iso(row.sim_time) if row.sim_time else "-"
        status = "done" if row.done else "running"
        return (
            f"  {row.name:<10} sent {row.sent:>8}  acked {row.acked:>8}  failed {row.failed:>6}"
            f"  simulated {when}  {status}"
        )
