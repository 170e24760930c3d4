"""The loads every comparison runs, shared by ``compare.py`` and ``growth.py``:
how a load is generated (wrk, else loadgen.py), the ingest and GET loads,
and the summary of repeated runs."""

from __future__ import annotations

import math
import sys
import time
from dataclasses import dataclass
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import common
import lawnmower
import wrkrun

POOL = 1000  # ingest entities notified in turn


@dataclass
class Runner:
    """How loads are generated: wrk if available (and not ``--loadgen``), else loadgen.py."""

    reps: int
    duration: float
    warmup: float
    use_wrk: bool

    def repeat(self, url: str, make, connections: int) -> list[dict]:
        """A warm-up run, then ``reps`` measured runs; ``make(tag)`` builds the
        load for one run (tag: "w", "1", "2", ...) as (wrk script, loadgen factory).
        The warm-up run is returned too, marked ``warmup`` (summaries skip it)."""
        runs = []
        if self.warmup > 0:
            runs.append({**self._one(url, *make("w"), connections, self.warmup), "warmup": True})
        return runs + [self._one(url, *make(str(i + 1)), connections, self.duration) for i in range(self.reps)]

    def _one(self, url: str, script: str, factory, connections: int, duration: float) -> dict:
        t0 = time.monotonic()
        if self.use_wrk:
            stats = wrkrun.run(url, script, connections, duration).to_dict()
        else:
            from loadgen import run_load

            host, port = _host_port(url)
            s = run_load(host, port, factory, connections=connections, duration=duration, warmup=0)
            stats = {
                "requests": s.total_requests,
                "ok": s.total_ok,
                "non_2xx": s.total_non_2xx,
                "errors": s.total_errors,
                "seconds": duration,
                "rps": s.rps,
                "p50_ms": s.p50_ms,
                "p90_ms": s.p90_ms,
                "p99_ms": s.p99_ms,
                "max_ms": s.max_ms,
                "mean_ms": math.nan,
            }
        stats["connections"] = connections
        stats["wall_s"] = round(time.monotonic() - t0, 2)
        return stats


def _host_port(url: str) -> tuple[str, int]:
    from urllib.parse import urlsplit

    parts = urlsplit(url)
    return parts.hostname, parts.port or 80


def ingest_load(url: str, run_id: str, ledger: list):
    """``make(tag)`` for the ingest runs; records each run's id in ``ledger``
    so the store check can find its notifications."""
    host, port = _host_port(url)
    hdrs = lawnmower.headers(lawnmower.INGEST_TENANT)

    def make(tag: str):
        rid = f"{run_id}{tag}"
        ledger.append(rid)
        prelude, expr = lawnmower.ingest_lua(rid, POOL)
        script = wrkrun.post_script("/v2/notify", hdrs, prelude, expr, threads=2)
        head = (
            f"POST /v2/notify HTTP/1.1\r\nHost: {host}:{port}\r\n"
            + "".join(f"{k}: {v}\r\n" for k, v in hdrs.items())
            + "Content-Length: "
        ).encode()

        def factory(seq: int) -> bytes:
            body = lawnmower.ingest_body(rid, seq, POOL)
            return head + str(len(body)).encode() + b"\r\n\r\n" + body

        return script, factory

    return make


def get_load(url: str, paths: list[str], headers: dict[str, str]):
    from loadgen import build_request

    host, port = _host_port(url)
    script = wrkrun.get_script(paths, headers)
    reqs = [build_request("GET", p, host, port, headers) for p in paths]

    def make(tag: str):
        return script, (lambda seq: reqs[seq % len(reqs)])

    return make


def summary(runs: list[dict], key: str) -> dict | None:
    """Median, min, max over the measured runs (the warm-up skipped)."""
    return common.spread(r.get(key) for r in runs if not r.get("warmup"))


# --- targets (servers) -----------------------------------------------------------------


# --- the store check ----------------------------------------------------------------------
