"""Replay the simulators against a service as Orion would, with a progress display.

Time: a simulator's instants are mapped to wall-clock time as
``(at - sim_start) / speedup``. With ``--duration D`` the simulated span is
``D * speedup`` and ends when the run ends (``sim_start = now + D - D *
speedup``): the data is live. At speed 1 it follows the clock; a faster
replay starts in the past and catches up with the clock at its last
instant, so it never writes the future and dashboards of "the last 15
minutes" show it. A run never goes back over data an earlier run left:
``live_window`` starts after it (and slows the replay to still end on
time). Which emissions are sent depends only on the seed, the speedup and
the duration, never on how fast the service answers: a slow service makes
the run late (the progress display says by how much), not different.

Where: by default the notifications go to the service's ``/v2/notify``,
exactly as Orion would send them. With ``mqtt`` they are published to that
MQTT broker instead, as Orion's ``mqttCustom`` would (``demo.mqtt``), for
the service to consume. With ``broker`` the entities go to that Orion
(NGSIv2) or, with ``ngsi_ld``, Orion-LD as entity updates
(``broker.updates``), and the broker notifies the service through its
subscriptions.

Wall time comes from a ``Timer``: ``WallTime`` (the default) follows the
machine's clock; ``VirtualTime`` jumps to the next emission due as soon as
every simulator waits for one, so a bounded run sends exactly the
notifications of a wall-clock run, as fast as the service acknowledges them
(tests and recorded feeds).

HTTP: ``concurrency`` sender tasks, each one keep-alive ``httpx.AsyncClient``
connection, fed by a small bounded queue: at most that many requests are in
flight, the way a broker's notification worker pool behaves. A non-2xx
answer or a transport error counts as failed; Orion would not retry it.
"""

from __future__ import annotations

import asyncio
import contextlib
import heapq
import importlib.util
import itertools
import random
import ssl
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta
from typing import Protocol, TextIO

import httpx

from tsdb_service.broker.subscriptions import MQTT_TOPIC, topic_of
from tsdb_service.broker.updates import update_request
from tsdb_service.usecases import orion
from tsdb_service.usecases.base import Simulator

NOTIFY_PATH = "/v2/notify"


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
    lag: float = 0.0  # wall seconds the latest emission was sent after it was due


@dataclass(frozen=True)
class RunConfig:
    url: str
    speedup: float = 1.0
    duration: float | None = None  # wall seconds; None runs until stopped
    seed: int = 0
    concurrency: int = 16
    start: datetime | None = None  # simulated start; default per the module docstring
    broker: str | None = None  # update the entities in this broker instead of notifying ``url``
    ngsi_ld: bool = False  # the broker is Orion-LD: NGSI-LD updates
    mqtt: str | None = None  # without ``broker``: publish the notifications to this MQTT broker

    @property
    def target(self) -> str:
        """The base URL requests go to: the broker, or the service."""
        return (self.broker or self.url).rstrip("/")


class Timer(Protocol):
    """Where a run's wall time comes from."""

    def monotonic(self) -> float:
        """Seconds on this timer's clock (only differences count)."""
        ...

    async def wait(self, stop: asyncio.Event, seconds: float) -> bool:
        """Let ``seconds`` pass; True if ``stop`` was set meanwhile."""
        ...

    def pacing(self) -> contextlib.AbstractContextManager[object]:
        """A simulator's hold on the clock, taken when called (before any
        simulator starts) and released when its ``with`` block ends."""
        ...


class WallTime:
    """The machine's clock: emissions are sent when they are due."""

    def monotonic(self) -> float:
        return time.monotonic()

    async def wait(self, stop: asyncio.Event, seconds: float) -> bool:
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

    def pacing(self) -> contextlib.AbstractContextManager[object]:
        return contextlib.nullcontext()


class VirtualTime:
    """A clock that never waits: when every simulator holding ``pacing()``
    waits, it jumps to the earliest wake-up (so every hold is taken before
    any simulator starts). Emissions keep their order and
    their schedule (no run is ever late on it), and one that waits for a free
    sender (backpressure) holds the clock, so the run goes exactly as fast as
    the service acknowledges."""

    def __init__(self) -> None:
        self.now = 0.0
        self._pacing = 0  # simulators not waiting on this clock
        self._sleepers: list[tuple[float, int, asyncio.Future[None]]] = []
        self._order = itertools.count()

    def monotonic(self) -> float:
        return self.now

    async def wait(self, stop: asyncio.Event, seconds: float) -> bool:
        if stop.is_set() or seconds <= 0:
            await asyncio.sleep(0)
            return stop.is_set()
        woken = asyncio.get_running_loop().create_future()
        heapq.heappush(self._sleepers, (self.now + seconds, next(self._order), woken))
        self._pacing -= 1
        self._advance()
        await woken
        return stop.is_set()

    def pacing(self) -> contextlib.AbstractContextManager[object]:
        self._pacing += 1
        hold = contextlib.ExitStack()
        hold.callback(self._release)
        return hold

    def _release(self) -> None:
        self._pacing -= 1
        self._advance()

    def _advance(self) -> None:
        if self._pacing == 0 and self._sleepers:
            at, _, woken = heapq.heappop(self._sleepers)
            self.now = max(self.now, at)
            self._pacing += 1  # counted from now, not from when its task resumes
            woken.set_result(None)


WALL_TIME = WallTime()


@dataclass
class _Clock:
    sim_start: datetime
    speedup: float
    duration: float | None = None  # planned wall seconds
    wall_start: float | None = None  # on ``timer``; default: now
    timer: Timer = WALL_TIME

    def __post_init__(self) -> None:
        if self.wall_start is None:
            self.wall_start = self.timer.monotonic()

    def due(self, at: datetime) -> float:
        """Wall seconds after the start at which ``at`` is to be sent."""
        return (at - self.sim_start).total_seconds() / self.speedup

    def elapsed(self) -> float:
        assert self.wall_start is not None  # set by __post_init__
        return self.timer.monotonic() - self.wall_start

    def lag(self, row: Stats) -> float:
        """Wall seconds ``row`` is behind its schedule (0 when on time or done)."""
        return 0.0 if row.done else row.lag

    def expected_end(self, rows: Sequence[Stats]) -> float | None:
        """Wall seconds after the start at which the slowest simulator will be
        done, at the pace each late one has kept so far; None when unbounded."""
        if self.duration is None:
            return None
        elapsed, ends = self.elapsed(), [self.duration]
        for row in rows:
            if self.lag(row) < BEHIND_NOTE_S or row.sim_time is None:
                continue
            progress = self.due(row.sim_time)  # planned seconds covered so far
            pace = progress / elapsed if elapsed > 0 else 1.0  # planned seconds per wall second
            ends.append(elapsed + (self.duration - progress) / pace if pace > 0 else float("inf"))
        return max(ends)


def default_start(speedup: float, duration: float | None, now: datetime | None = None) -> datetime:
    """A bounded run ends when it ends (live); an open-ended one starts now."""
    return live_window(speedup, duration, now or datetime.now(UTC))[0]


def live_window(
    speedup: float, duration: float | None, now: datetime, previous_end: datetime | None = None
) -> tuple[datetime, float]:
    """(simulated start, speedup) of a run starting at ``now``.

    Bounded runs end at ``now + duration``: the span ``duration * speedup``
    starts that far before (at speed 1, now; below speed 1, now too, since
    ending on time would mean starting in the future). ``previous_end`` is
    the newest instant an earlier run stored: the run starts just after it
    and, if that shortens the span, replays it more slowly so that it still
    ends on time. Rounded to the millisecond, as Orion's timestamps are.
    """
    start = now
    if duration is not None and speedup > 1:
        start = now + timedelta(seconds=duration) - timedelta(seconds=duration * speedup)
    if previous_end is not None and start <= previous_end:
        start = previous_end + RUN_GAP
        end = now + timedelta(seconds=duration or 0)
        if duration is not None and speedup > 1:
            if start >= end:
                raise ValueError(
                    f"the data of an earlier run reaches {previous_end.isoformat(timespec='seconds')}, "
                    "beyond this run's end: wait until then, or use another --db"
                )
            speedup = (end - start).total_seconds() / duration
    return _ms(start), speedup


RUN_GAP = timedelta(milliseconds=1)


def _ms(t: datetime) -> datetime:
    return t.replace(microsecond=t.microsecond // 1000 * 1000)


def rng_for(seed: int, name: str, purpose: str = "physics") -> random.Random:
    """An independent stream per simulator and purpose, so adding one never shifts another."""
    return random.Random(f"{seed}:{name}:{purpose}")


async def run(
    simulators: Sequence[Simulator],
    config: RunConfig,
    *,
    progress: Progress | None = None,
    stop: asyncio.Event | None = None,
    timer: Timer = WALL_TIME,
) -> dict[str, Stats]:
    """Send every simulator's notifications until the duration ends or ``stop`` is set."""
    if config.speedup <= 0 or config.concurrency < 1:
        raise ValueError("speedup and concurrency must be positive")
    stop = stop or asyncio.Event()
    start = config.start or default_start(config.speedup, config.duration)
    clock = _Clock(start, config.speedup, config.duration, timer=timer)
    stats = {sim.name: Stats(sim.name) for sim in simulators}
    outbox: asyncio.Queue = asyncio.Queue(maxsize=2 * config.concurrency)
    publisher = None
    if config.mqtt and not config.broker:
        from tsdb_service.demo.mqtt import MqttPublisher

        publisher = MqttPublisher(config.mqtt)
        senders = [asyncio.create_task(_mqtt_sender(publisher, outbox)) for _ in range(config.concurrency)]
    else:
        tls = _client_tls()
        senders = [asyncio.create_task(_sender(config.target, outbox, tls)) for _ in range(config.concurrency)]
    reporter = asyncio.create_task(progress.follow(stats, clock)) if progress else None
    try:
        holds = [timer.pacing() for _ in simulators]
        await asyncio.gather(
            *(
                _drive(sim, clock, config, stats[sim.name], outbox, stop, hold)
                for sim, hold in zip(simulators, holds, strict=True)
            )
        )
    finally:
        for _ in senders:
            await outbox.put(None)
        await asyncio.gather(*senders, return_exceptions=True)
        if publisher is not None:
            publisher.close()
        if progress is not None and reporter is not None:
            reporter.cancel()
            await asyncio.gather(reporter, return_exceptions=True)
            progress.final(stats, clock)
    return stats


async def _drive(sim, clock: _Clock, config, stats: Stats, outbox: asyncio.Queue, stop: asyncio.Event, hold) -> None:
    """Pace one simulator's emissions onto the clock and queue them for the senders."""
    physics, wire = rng_for(config.seed, sim.name), rng_for(config.seed, sim.name, "orion")
    subscription = orion.subscription_id(wire)
    with hold:
        for emission in sim.emissions(clock.sim_start, physics):
            due = clock.due(emission.at)
            if config.duration is not None and due > config.duration:
                break
            wait = due - clock.elapsed()
            stats.lag = max(0.0, -wait)
            if await clock.timer.wait(stop, wait):
                break
            if config.broker:
                path, headers, body = update_request(sim, emission.entity, config.ngsi_ld)
            elif config.mqtt:  # the topic, and no headers: MQTT has none
                path, headers = topic_of(sim, MQTT_TOPIC), {}
                body = orion.notification_body(subscription, emission.entity)
            else:
                path = NOTIFY_PATH
                headers = orion.notification_headers(
                    sim.tenancy.service, sim.tenancy.service_path, orion.correlator(wire)
                )
                body = orion.notification_body(subscription, emission.entity)
            await outbox.put((stats, path, headers, body))  # blocks while every sender is busy: backpressure
            stats.sent += 1
            stats.sim_time = emission.at
        stats.done = True


def _client_tls() -> ssl.SSLContext:
    """One TLS context for every sender: httpx builds one per client
    otherwise, loading the CA bundle each time (tens of ms apiece)."""
    return httpx.create_ssl_context()


async def _sender(url: str, outbox: asyncio.Queue, tls: ssl.SSLContext) -> None:
    """One keep-alive connection posting queued notifications until it gets ``None``.

    A client per connection rather than one shared pool: httpcore's pool
    scans every connection on every request, which doubles the client's cost
    per notification at 16 connections.
    """
    limits = httpx.Limits(max_connections=1, max_keepalive_connections=1)
    async with httpx.AsyncClient(base_url=url, timeout=30.0, limits=limits, verify=tls) as client:
        while (item := await outbox.get()) is not None:
            await _post(client, *item)


async def _mqtt_sender(publisher, outbox: asyncio.Queue) -> None:
    """Publish queued notifications until ``None``; acknowledged: the broker has it."""
    while (item := await outbox.get()) is not None:
        stats, topic, _, body = item
        try:
            await publisher.publish(topic, body)
            stats.acked += 1
        except Exception as exc:
            stats.failed += 1
            stats.last_error = f"{type(exc).__name__}: {exc}"


async def _post(client: httpx.AsyncClient, stats: Stats, path: str, headers: dict, body: bytes) -> None:
    try:
        response = await client.post(path, content=body, headers=headers)
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
        over = clock.elapsed() - clock.duration if clock.duration is not None else 0.0
        if over > OVERRUN_NOTE_S and all(row.done for row in stats.values()):
            self.stream.write(
                f"  the run took {clock.elapsed():.1f} s for --duration {clock.duration:g}: {over:.1f} s over, "
                f"the simulators could not keep up with x{clock.speedup:.3g} (a lower --speedup keeps time)\n"
            )
        self.stream.flush()

    def _draw(self, stats: dict[str, Stats], clock: _Clock) -> None:
        lines = [self.line(row, clock.lag(row)) for row in stats.values()]
        lines.append(self.summary(stats, clock))
        if self.tty:
            if self._drawn:
                self.stream.write(f"\x1b[{self._drawn}F")
            self.stream.write("".join(f"{line}\x1b[K\n" for line in lines))
            self._drawn = len(lines)
        else:
            self.stream.write("\n".join(lines) + "\n")
        self.stream.flush()

    @staticmethod
    def summary(stats: dict[str, Stats], clock: _Clock) -> str:
        """Elapsed time, and when behind schedule: by how much and when the run will end."""
        elapsed = clock.elapsed()
        text = f"  elapsed {elapsed:7.1f} s   speedup x{clock.speedup:.3g}"
        lag = max((clock.lag(row) for row in stats.values()), default=0.0)
        end = clock.expected_end(list(stats.values()))
        if lag < BEHIND_NOTE_S or end is None or clock.duration is None:
            return text
        finish = datetime.now().astimezone() + timedelta(seconds=max(0.0, end - elapsed))
        return (
            f"{text}   BEHIND by {lag:.1f} s: ends in ~{max(0.0, end - elapsed):.0f} s "
            f"(~{finish:%H:%M:%S}), {max(0.0, end - clock.duration):.0f} s after --duration {clock.duration:g}"
        )

    @staticmethod
    def line(row: Stats, lag: float = 0.0) -> str:
        when = orion.iso(row.sim_time) if row.sim_time else "-"
        status = "done" if row.done else f"behind {lag:.1f} s" if lag >= BEHIND_NOTE_S else "running"
        return (
            f"  {row.name:<10} sent {row.sent:>8}  acked {row.acked:>8}  failed {row.failed:>6}"
            f"  simulated {when}  {status}"
        )


BEHIND_NOTE_S = 1.0  # lag shown from this many seconds behind schedule
OVERRUN_NOTE_S = 1.0
