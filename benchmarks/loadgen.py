"""A minimal, cheap HTTP/1.1 keep-alive load generator.

The benchmarks run the load generator on the same small machine as the server
under test, so every CPU cycle it spends is taken from the server. httpx and
aiohttp cost tens of microseconds per request; this client costs a few: each
connection is an ``asyncio.Protocol`` that writes pre-encoded request bytes,
parses only the status line and the body framing (``Content-Length`` or
chunked), records the latency with ``perf_counter`` and immediately sends the
next request (a closed loop: ``connections`` requests are always in flight).

The load runs in a separate process (``processes=1`` by default) with uvloop
when it is installed, so it neither shares an interpreter with the caller nor
needs the caller to be async.

Usage::

    from loadgen import build_request, run_load

    def factory(seq: int) -> bytes:
        return build_request("GET", f"/v2/entities/e{seq}", "127.0.0.1", 8668)

    stats = run_load("127.0.0.1", 8668, factory, connections=32, duration=10, warmup=2)
    print(stats.rps, stats.p50_ms, stats.p99_ms)

``request_factory(seq)`` is called once per request with a sequence number
that is unique across all connections and processes of one ``run_load`` call
(0, 1, 2, ...), so requests can carry unique ids. It must return the complete
request bytes (request line, headers including ``Host`` and
``Content-Length``, body); ``build_request`` makes them. With processes >= 1
the factory is handed to the worker processes by fork (Linux) or pickling.

Requests are counted in the measured window if they *started* after the
warmup; the ones in flight when the duration ends are awaited (up to
``drain_timeout``) and counted. Latency is that of a closed loop: it includes
the time a request waits on the server, not the time it would have waited to
be sent on an open-loop schedule.
"""

from __future__ import annotations

import asyncio
import gc
import math
import multiprocessing
import os
import time
from array import array
from collections import Counter
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass, field
from typing import Any

try:  # optional, but much cheaper per request
    import uvloop
except ImportError:  # pragma: no cover
    uvloop = None

__all__ = ["LoadStats", "build_request", "run_load", "run_load_async"]

RequestFactory = Callable[[int], bytes]

_ALLOWED_HOSTS = frozenset({"127.0.0.1", "localhost", "::1"})
_perf = time.perf_counter


def build_request(
    method: str,
    target: str,
    host: str,
    port: int,
    headers: Mapping[str, str] | None = None,
    body: bytes | None = None,
) -> bytes:
    """Encode one HTTP/1.1 keep-alive request."""
    lines = [f"{method} {target} HTTP/1.1", f"Host: {host}:{port}"]
    for name, value in (headers or {}).items():
        lines.append(f"{name}: {value}")
    if body is not None or method in ("POST", "PUT", "PATCH"):
        lines.append(f"Content-Length: {len(body or b'')}")
    head = ("\r\n".join(lines) + "\r\n\r\n").encode("latin-1")
    return head + body if body else head


# --------------------------------------------------------------------------
# results


@dataclass
class LoadStats:
    """What one ``run_load`` measured. Times in milliseconds, rates per second.

    ``requests``/``ok``/``non_2xx``/``errors`` cover the measured window only;
    ``total_*`` cover warmup + measured window, which is what a store must
    hold afterwards.
    """

    connections: int
    processes: int
    warmup_s: float
    duration_s: float
    requests: int = 0  # responses received in the measured window
    ok: int = 0  # of which 2xx
    non_2xx: int = 0
    errors: int = 0  # connection failures/resets, incomplete at drain timeout
    rps: float = 0.0  # 2xx responses per second of measured window
    p50_ms: float = math.nan
    p90_ms: float = math.nan
    p99_ms: float = math.nan
    max_ms: float = math.nan
    mean_ms: float = math.nan
    total_sent: int = 0
    total_ok: int = 0
    total_non_2xx: int = 0
    total_errors: int = 0
    status_counts: dict[str, int] = field(default_factory=dict)
    generator_cpu_pct: float = math.nan  # CPU the generator used in the window
    error_samples: list[str] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        return {k: (None if isinstance(v, float) and math.isnan(v) else v) for k, v in asdict(self).items()}


def _percentile(sorted_values: list[float], q: float) -> float:
    """Nearest-rank percentile of an already sorted list."""
    if not sorted_values:
        return math.nan
    rank = max(1, math.ceil(q / 100.0 * len(sorted_values)))
    return sorted_values[rank - 1]


# --------------------------------------------------------------------------
# the client


class _Conn(asyncio.Protocol):
    __slots__ = ("buf", "busy", "closed", "run", "t_start", "transport")

    def __init__(self, run: _Run):
        self.run = run
        self.transport: asyncio.Transport | None = None
        self.buf = bytearray()
        self.t_start = 0.0
        self.busy = False  # a request is in flight
        self.closed = False

    # -- asyncio callbacks

    def connection_made(self, transport):  # type: ignore[override]
        self.transport = transport
        self.run.conns.add(self)
        self.run.send_next(self)

    def data_received(self, data: bytes) -> None:
        buf = self.buf
        buf += data
        while self.busy:
            try:
                done = _parse_response(buf)
            except ValueError as exc:
                self.busy = False
                self.run.on_error(self, str(exc))
                self.closed = True
                self.transport.close()
                self.run.reconnect_later()
                return
            if done is None:
                return
            status, consumed, close = done
            del buf[:consumed]
            self.busy = False
            self.run.on_response(self, status)
            if close:
                self.closed = True
                self.transport.close()
                self.run.reconnect_later()
                return
            self.run.send_next(self)
        if buf:  # bytes without a request: the server is confused
            self.run.note_error("unsolicited bytes from server")
            buf.clear()

    def connection_lost(self, exc: Exception | None) -> None:
        if self.busy:
            self.busy = False
            self.run.on_error(self, f"connection lost: {exc!r}")
            self.run.reconnect_later()
        elif not self.closed and not self.run.stopping:
            self.run.reconnect_later()
        self.closed = True
        self.run.conns.discard(self)
        self.run.check_done()


def _parse_response(buf: bytearray) -> tuple[int, int, bool] | None:
    """(status, bytes consumed, server closes) for one complete response at
    the start of ``buf``, or None if it is not complete yet."""
    end = buf.find(b"\r\n\r\n")
    if end < 0:
        return None
    head = bytes(buf[:end]).lower()
    status = int(head[9:12])
    body_start = end + 4
    close = b"\r\nconnection: close" in head
    i = head.find(b"\r\ncontent-length:")
    if i >= 0:
        j = head.find(b"\r\n", i + 2)
        length = int(head[i + 17 : j if j >= 0 else len(head)])
        if len(buf) < body_start + length:
            return None
        return status, body_start + length, close
    if b"\r\ntransfer-encoding: chunked" in head:
        pos = body_start
        while True:
            eol = buf.find(b"\r\n", pos)
            if eol < 0:
                return None
            size = int(bytes(buf[pos:eol]).split(b";", 1)[0], 16)
            pos = eol + 2
            if size == 0:
                # optional trailers, then an empty line
                while True:
                    eol = buf.find(b"\r\n", pos)
                    if eol < 0:
                        return None
                    if eol == pos:
                        return status, eol + 2, close
                    pos = eol + 2
            pos += size + 2
            if len(buf) < pos:
                return None
    if 100 <= status < 200 or status in (204, 304):
        return status, body_start, close
    # no framing: body runs to connection close; we do not support that
    raise ValueError(f"response without Content-Length or chunked framing: {head[:200]!r}")


class _Run:
    """State of one event loop's share of the load."""

    def __init__(
        self,
        host: str,
        port: int,
        factory: RequestFactory,
        connections: int,
        warmup: float,
        duration: float,
        seq_start: int,
        seq_step: int,
    ):
        self.host, self.port = host, port
        self.factory = factory
        self.n_conns = connections
        self.seq = seq_start
        self.seq_step = seq_step
        self.t0 = _perf()
        self.t_measure = self.t0 + warmup
        self.t_end = self.t_measure + duration
        self.cpu_measure_start: float | None = None
        self.cpu_measure_end: float | None = None
        self.stopping = False
        self.conns: set[_Conn] = set()
        self.pending_connects = 0
        self.latencies = array("d")
        self.statuses: Counter[int] = Counter()  # measured window
        self.errors = 0
        self.total_sent = 0
        self.total_ok = 0
        self.total_non_2xx = 0
        self.total_errors = 0
        self.error_samples: list[str] = []
        self.loop = asyncio.get_running_loop()
        self.done = self.loop.create_future()

    # -- requests

    def send_next(self, conn: _Conn) -> None:
        now = _perf()
        if now >= self.t_end or self.stopping:
            self.stopping = True
            if self.cpu_measure_end is None:
                self.cpu_measure_end = time.process_time()
            conn.closed = True
            conn.transport.close()
            return
        if self.cpu_measure_start is None and now >= self.t_measure:
            self.cpu_measure_start = time.process_time()
        data = self.factory(self.seq)
        self.seq += self.seq_step
        conn.busy = True
        conn.t_start = _perf()
        conn.transport.write(data)
        self.total_sent += 1

    def on_response(self, conn: _Conn, status: int) -> None:
        now = _perf()
        ok = 200 <= status < 300
        if ok:
            self.total_ok += 1
        else:
            self.total_non_2xx += 1
        if conn.t_start >= self.t_measure:
            self.latencies.append(now - conn.t_start)
            self.statuses[status] += 1

    def on_error(self, conn: _Conn, what: str) -> None:
        self.total_errors += 1
        if conn.t_start >= self.t_measure:
            self.errors += 1
        self.note_error(what)

    def note_error(self, what: str) -> None:
        if len(self.error_samples) < 5:
            self.error_samples.append(what)

    # -- connections

    def reconnect_later(self) -> None:
        if self.stopping or _perf() >= self.t_end:
            return
        self.pending_connects += 1
        self.loop.call_later(0.01, lambda: self.loop.create_task(self._connect()))

    async def _connect(self) -> None:
        try:
            await self.loop.create_connection(lambda: _Conn(self), self.host, self.port)
        except OSError as exc:
            self.total_errors += 1
            if _perf() >= self.t_measure:
                self.errors += 1
            self.note_error(f"connect failed: {exc!r}")
            self.pending_connects -= 1
            if not self.stopping and _perf() < self.t_end:
                await asyncio.sleep(0.1)
                self.pending_connects += 1
                self.loop.create_task(self._connect())
            self.check_done()
            return
        self.pending_connects -= 1
        self.check_done()

    def check_done(self) -> None:
        if self.stopping and not self.conns and self.pending_connects == 0 and not self.done.done():
            self.done.set_result(None)

    async def go(self, drain_timeout: float) -> None:
        for _ in range(self.n_conns):
            self.pending_connects += 1
            self.loop.create_task(self._connect())
        # stop sending at t_end, then wait for the requests in flight
        await asyncio.sleep(max(0.0, self.t_end - _perf()))
        self.stopping = True
        if self.cpu_measure_end is None:
            self.cpu_measure_end = time.process_time()
        for conn in list(self.conns):
            if not conn.busy and not conn.closed:
                conn.closed = True
                conn.transport.close()
        self.check_done()
        try:
            await asyncio.wait_for(asyncio.shield(self.done), drain_timeout)
        except TimeoutError:
            for conn in list(self.conns):
                if conn.busy:
                    conn.busy = False
                    self.on_error(conn, "no response before drain timeout")
                conn.closed = True
                conn.transport.abort()
            self.pending_connects = 0
            await asyncio.sleep(0)

    def result(self) -> dict[str, Any]:
        cpu = math.nan
        if self.cpu_measure_start is not None and self.cpu_measure_end is not None:
            cpu = self.cpu_measure_end - self.cpu_measure_start
        return {
            "latencies": self.latencies.tobytes(),
            "statuses": dict(self.statuses),
            "errors": self.errors,
            "total_sent": self.total_sent,
            "total_ok": self.total_ok,
            "total_non_2xx": self.total_non_2xx,
            "total_errors": self.total_errors,
            "error_samples": self.error_samples,
            "cpu_s": cpu,
        }


async def _run_part(
    host: str,
    port: int,
    factory: RequestFactory,
    connections: int,
    duration: float,
    warmup: float,
    seq_start: int,
    seq_step: int,
    drain_timeout: float,
) -> dict[str, Any]:
    run = _Run(host, port, factory, connections, warmup, duration, seq_start, seq_step)
    await run.go(drain_timeout)
    return run.result()


def _worker(args: tuple, conn) -> None:
    gc.disable()  # a gen-2 pass on a big latency list is a latency spike
    try:
        coro = _run_part(*args)
        loop = uvloop.new_event_loop() if uvloop is not None else asyncio.new_event_loop()
        try:
            result = loop.run_until_complete(coro)
        finally:
            loop.close()
        conn.send(result)
    except BaseException as exc:  # report, never hang the parent
        conn.send({"exception": repr(exc)})
    finally:
        conn.close()


def _merge(parts: list[dict[str, Any]], connections: int, processes: int, warmup: float, duration: float) -> LoadStats:
    latencies: list[float] = []
    statuses: Counter[int] = Counter()
    stats = LoadStats(connections=connections, processes=processes, warmup_s=warmup, duration_s=duration)
    cpu = 0.0
    for part in parts:
        lat = array("d")
        lat.frombytes(part["latencies"])
        latencies.extend(lat)
        statuses.update(part["statuses"])
        stats.errors += part["errors"]
        stats.total_sent += part["total_sent"]
        stats.total_ok += part["total_ok"]
        stats.total_non_2xx += part["total_non_2xx"]
        stats.total_errors += part["total_errors"]
        for sample in part["error_samples"]:
            if len(stats.error_samples) < 5:
                stats.error_samples.append(sample)
        cpu += part["cpu_s"]
    latencies.sort()
    stats.requests = len(latencies)
    stats.ok = sum(n for s, n in statuses.items() if 200 <= s < 300)
    stats.non_2xx = stats.requests - stats.ok
    stats.status_counts = {str(s): n for s, n in sorted(statuses.items())}
    stats.rps = stats.ok / duration if duration > 0 else math.nan
    stats.generator_cpu_pct = 100.0 * cpu / duration if duration > 0 else math.nan
    if latencies:
        stats.p50_ms = 1000 * _percentile(latencies, 50)
        stats.p90_ms = 1000 * _percentile(latencies, 90)
        stats.p99_ms = 1000 * _percentile(latencies, 99)
        stats.max_ms = 1000 * latencies[-1]
        stats.mean_ms = 1000 * sum(latencies) / len(latencies)
    return stats


def _check_args(host: str, connections: int, duration: float, warmup: float) -> None:
    if host not in _ALLOWED_HOSTS:
        raise ValueError(f"loadgen only targets the local machine, not {host!r}")
    if connections < 1:
        raise ValueError("connections must be >= 1")
    if not (0 < duration <= 3600) or not (0 <= warmup <= 600):
        raise ValueError("duration must be in (0, 3600] s and warmup in [0, 600] s")


async def run_load_async(
    host: str,
    port: int,
    request_factory: RequestFactory,
    connections: int = 32,
    duration: float = 10.0,
    warmup: float = 2.0,
    drain_timeout: float = 10.0,
) -> LoadStats:
    """``run_load`` on the caller's running event loop (no extra process)."""
    _check_args(host, connections, duration, warmup)
    part = await _run_part(host, port, request_factory, connections, duration, warmup, 0, 1, drain_timeout)
    return _merge([part], connections, 0, warmup, duration)


def run_load(
    host: str,
    port: int,
    request_factory: RequestFactory,
    connections: int = 32,
    duration: float = 10.0,
    warmup: float = 2.0,
    *,
    processes: int = 1,
    drain_timeout: float = 10.0,
) -> LoadStats:
    """Drive ``connections`` keep-alive connections in a closed loop for
    ``warmup`` + ``duration`` seconds and return what the measured window saw.

    ``processes`` load-generating processes share the connections (0 runs the
    loop in this process). Blocks until the load is over; never runs longer
    than warmup + duration + drain_timeout (+ process start-up).
    """
    _check_args(host, connections, duration, warmup)
    if processes <= 0:
        loop = uvloop.new_event_loop() if uvloop is not None else asyncio.new_event_loop()
        try:
            return loop.run_until_complete(
                run_load_async(host, port, request_factory, connections, duration, warmup, drain_timeout)
            )
        finally:
            loop.close()

    processes = min(processes, connections)
    method = "fork" if "fork" in multiprocessing.get_all_start_methods() else "spawn"
    ctx = multiprocessing.get_context(method)
    workers = []
    for k in range(processes):
        share = connections // processes + (1 if k < connections % processes else 0)
        parent_end, child_end = ctx.Pipe(duplex=False)
        args = (host, port, request_factory, share, duration, warmup, k, processes, drain_timeout)
        proc = ctx.Process(target=_worker, args=(args, child_end), name=f"loadgen-{k}", daemon=True)
        proc.start()
        child_end.close()
        workers.append((proc, parent_end))

    deadline = time.monotonic() + warmup + duration + drain_timeout + 30.0
    parts, failures = [], []
    for proc, pipe in workers:
        remaining = max(0.1, deadline - time.monotonic())
        if pipe.poll(remaining):
            try:
                part = pipe.recv()
            except EOFError:
                part = {"exception": f"{proc.name} exited with code {proc.exitcode} without a result"}
        else:
            part = {"exception": f"{proc.name} gave no result in time"}
        if "exception" in part:
            failures.append(part["exception"])
        else:
            parts.append(part)
    for proc, pipe in workers:
        proc.join(5)
        if proc.is_alive():
            proc.kill()
            proc.join()
        pipe.close()
    if failures:
        raise RuntimeError("load generator failed: " + "; ".join(failures))
    return _merge(parts, connections, processes, warmup, duration)


if __name__ == "__main__":  # tiny smoke run: python loadgen.py PORT [PATH]
    import sys

    _port = int(sys.argv[1])
    _path = sys.argv[2] if len(sys.argv) > 2 else "/"
    _req = build_request("GET", _path, "127.0.0.1", _port)
    print(
        run_load("127.0.0.1", _port, lambda seq: _req, connections=8, duration=2, warmup=0.5).to_dict()
        | {"pid": os.getpid()}
    )
