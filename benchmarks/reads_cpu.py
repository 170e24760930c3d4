"""CPU per request of compare.py's three read queries, on a noisy machine.

    .venv/bin/python benchmarks/reads_cpu.py                          # DuckDB and PostgreSQL
    .venv/bin/python benchmarks/reads_cpu.py --backends postgresql --requests 400 --reps 5

Wall latency under a load average of 10 on 2 cores says little; the CPU a
request costs does not depend on how many other processes share the cores.
For each backend this starts our server (as compare.py does: a temporary
DuckDB file, or a fresh database on a private PostgreSQL cluster), POSTs
compare.py's query data set (20 Lawnmower entities x 1 day, one sample per
minute) over HTTP, then for each query -- lastN=100 on one entity attribute,
the type-level hourly average over the day, the type-level lastN=1000 --
sends ``--requests`` GETs one after the other on one keep-alive connection,
``--reps`` times, and prints per rep: the server's CPU ms per request
(user + system of its process), on PostgreSQL also the database's (all its
processes), and the client's p50 latency. On PostgreSQL the data set is
VACUUMed before the measurement (``--no-vacuum``: not). Every cell is the median [min-max]
over the reps. ``--json FILE`` writes the raw figures.
"""

from __future__ import annotations

import argparse
import http.client
import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import common
import lawnmower
from common import Server, free_port, ours_cmd, spawned

QUERIES = ("lastN", "hourly_avg", "type_lastN")


def run_queries(server: Server, cluster, requests: int, reps: int) -> dict[str, list[dict]]:
    """Sequential GETs per query; CPU of the server (and database) per request."""
    paths = lawnmower.query_paths()
    conn = http.client.HTTPConnection("127.0.0.1", server.port, timeout=60)
    headers = lawnmower.query_headers()
    out: dict[str, list[dict]] = {}
    for name in QUERIES:
        group = paths[name]
        for i in range(max(20, requests // 5)):  # warm-up
            _get(conn, group[i % len(group)], headers)
        runs = []
        for _ in range(reps):
            cpu0 = server.cpu_seconds()
            db0 = cluster.cpu_seconds() if cluster else 0.0
            lat = []
            for i in range(requests):
                t0 = time.perf_counter()
                _get(conn, group[i % len(group)], headers)
                lat.append((time.perf_counter() - t0) * 1000)
            cpu = (server.cpu_seconds() - cpu0) * 1000 / requests
            db = ((cluster.cpu_seconds() - db0) * 1000 / requests) if cluster else None
            runs.append({"cpu_ms": cpu, "db_cpu_ms": db, "p50_ms": statistics.median(lat)})
        out[name] = runs
        print(f"  {name:11s} " + _cells(runs), flush=True)
    conn.close()
    return out


def _get(conn: http.client.HTTPConnection, path: str, headers: dict) -> None:
    conn.request("GET", path, headers=headers)
    resp = conn.getresponse()
    body = resp.read()
    if resp.status != 200:
        raise RuntimeError(f"{path} answered {resp.status}: {body[:200]!r}")


def _cell(runs: list[dict], key: str) -> str:
    s = common.spread(r.get(key) for r in runs)
    if s is None:
        return "-"
    return f"{s['median']:.2f} [{s['min']:.2f}-{s['max']:.2f}]"


def _cells(runs: list[dict]) -> str:
    text = f"server CPU ms/req {_cell(runs, 'cpu_ms')}  p50 ms {_cell(runs, 'p50_ms')}"
    if runs and runs[0].get("db_cpu_ms") is not None:
        text += f"  database CPU ms/req {_cell(runs, 'db_cpu_ms')}"
    return text


def run_backend(backend: str, workdir: Path, requests: int, reps: int, vacuum: bool = True) -> dict:
    cluster = None
    try:
        if backend == "postgresql":
            from pgutil import BenchCluster

            cluster = BenchCluster("readscpu").start()
            db = cluster.url
        else:
            db = str(workdir / "reads.duckdb")
        port = free_port()
        server = spawned(backend, ours_cmd(db, port, 1), port, workdir)
        server.start()
        try:
            print(f"- {backend}: loading the data set ...", flush=True)
            lawnmower.load_dataset(server.url)
            lawnmower.check_dataset(server.url)
            if cluster is not None and vacuum:
                cluster.vacuum_analyze()  # as autovacuum will, sooner or later
            return run_queries(server, cluster, requests, reps)
        finally:
            server.stop()
    finally:
        if cluster is not None:
            cluster.stop()


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--backends", default="duckdb,postgresql")
    ap.add_argument("--requests", type=int, default=300, help="GETs per rep and query")
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument(
        "--no-vacuum",
        action="store_true",
        help="PostgreSQL: measure right after the load, before any VACUUM (as compare.py does)",
    )
    ap.add_argument("--json", type=Path)
    args = ap.parse_args(argv)
    results = {}
    with tempfile.TemporaryDirectory(prefix="reads-cpu-") as tmp:
        for backend in args.backends.split(","):
            results[backend] = run_backend(backend, Path(tmp), args.requests, args.reps, not args.no_vacuum)
    if args.json:
        common.write_json(args.json, results, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
