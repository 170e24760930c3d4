"""A light tenant's reads beside many heavy ones: latency and memory (issue 37, finding 5).

    .venv/bin/python benchmarks/read_fairness.py       # the defaults: 600,000 samples, 24 readers, 30 s
    .venv/bin/python benchmarks/read_fairness.py --readers 48 --seconds 40 --json out.json
    .venv/bin/python benchmarks/read_fairness.py --env TSDB_READ_CONCURRENCY=1024 \
        --env TSDB_READ_ROWS_IN_FLIGHT=1000000000

Writes a DuckDB store (tenant ``heavy``: one series of ``--samples``
samples a second apart; tenant ``light``: a lamp's five samples), starts
``tsdb-service serve`` on it with the default read budgets (``--env``
overrides any setting, e.g. to approach the service without a shared read
pool as in the last line), then for ``--seconds``: ``--readers`` threads
of tenant ``heavy`` (in a process of their own) alternate an aggregation
per second over the whole series (more rows than ``TSDB_READ_MAX_ROWS``:
refused, 422, after reading them) and a Grafana SimpleJSON query of its
raw points, while this process times the light tenant's five-row read and
``/version``, and samples the server's resident memory.

Targets (issue 37): the light read's p99 at most 250 ms, and the peak RSS
within the bound docs/security.md states. Run it on a quiet machine: with
other processes on the cores the figures say little.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import httpx

from tests.support.memory import peak_rss_mib
from tests.support.read_load import light_latencies, percentile, prepare, start_heavy
from tests.support.server import ServerProcess


def _version_latencies(url: str, seconds: float, pause: float = 0.05) -> list[float]:
    out = []
    until = time.monotonic() + seconds
    with httpx.Client(base_url=url, timeout=60) as client:
        while time.monotonic() < until:
            start = time.perf_counter()
            client.get("/version").raise_for_status()
            out.append(time.perf_counter() - start)
            time.sleep(pause)
    return out


def _figures(latencies: list[float]) -> dict[str, float]:
    return {
        "n": len(latencies),
        "p50_ms": round(percentile(latencies, 50) * 1000, 1),
        "p95_ms": round(percentile(latencies, 95) * 1000, 1),
        "p99_ms": round(percentile(latencies, 99) * 1000, 1),
        "max_ms": round(max(latencies) * 1000, 1),
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=600_000, help="the heavy tenant's samples (default 600000)")
    parser.add_argument("--readers", type=int, default=24, help="heavy reader threads (default 24)")
    parser.add_argument("--seconds", type=float, default=30.0, help="how long they read (default 30)")
    parser.add_argument("--env", action="append", default=[], metavar="TSDB_X=V", help="a server setting")
    parser.add_argument("--json", metavar="FILE", help="write the figures here too")
    args = parser.parse_args()
    env = dict(item.split("=", 1) for item in args.env)
    with tempfile.TemporaryDirectory(prefix="tsdb-fairness-") as tmp:
        db = str(Path(tmp) / "reads.duckdb")
        print(f"writing {args.samples} samples...", file=sys.stderr)
        prepare(db, args.samples)
        with ServerProcess(db, extra_env=env, log_dir=tmp) as server:
            idle = light_latencies(server.url, 2.0)
            heavy = start_heavy(server.url, args.seconds, args.readers)
            time.sleep(1.0)
            window = args.seconds - 2.0
            peak: dict[str, int] = {}
            sampler = threading.Thread(
                target=lambda: peak.setdefault("rss", peak_rss_mib(server.pid, time.monotonic() + window))
            )
            version: list[float] = []
            other = threading.Thread(target=lambda: version.extend(_version_latencies(server.url, window)))
            sampler.start()
            other.start()
            light = light_latencies(server.url, window)
            sampler.join()
            other.join()
            outcome, _ = heavy.communicate(timeout=600)
    figures = {
        "samples": args.samples,
        "readers": args.readers,
        "seconds": args.seconds,
        "settings": env,
        "light_idle": _figures(idle),
        "light_under_load": _figures(light),
        "version_under_load": _figures(version),
        "peak_rss_mib": peak.get("rss"),
        "heavy_answers": dict(item.split("=") for item in outcome.split()),
    }
    print(json.dumps(figures, indent=2))
    verdict = figures["light_under_load"]["p99_ms"] <= 250
    print(f"light p99 {figures['light_under_load']['p99_ms']} ms: {'met' if verdict else 'NOT met'} (target 250 ms)")
    if args.json:
        Path(args.json).write_text(json.dumps(figures, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
