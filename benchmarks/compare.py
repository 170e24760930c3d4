"""Issue 15's comparison in one command: ours (DuckDB, PostgreSQL with 1 and 2
workers), a bare FastAPI ceiling and any running service (QuantumLeap ...),
side by side, with the issue's targets as PASS/FAIL.

    .venv/bin/python benchmarks/compare.py                          # everything, ~25 min
    .venv/bin/python benchmarks/compare.py --quick                  # 1 rep, short windows, no geo (~5 min)
    .venv/bin/python benchmarks/compare.py --url ql=http://host:8668 # + a running QuantumLeap, loaded over HTTP
    .venv/bin/python benchmarks/compare.py --ours none --url x=http://host:8668   # only that service
    .venv/bin/python benchmarks/compare.py --only ingest --ours duckdb --reps 3
    .venv/bin/python benchmarks/compare.py --only growth --sizes 1M,10M,100M    # the growth curve (growth.py)

Per target, one after the other (never two loads at once):

1. ingest: Orion-normalized notifications of a 5-attribute Lawnmower entity
   (``lawnmower.py``; 1,000 entities in turn, every body unique), tenant
   ``benchingest``, at 16 and at 64 connections; a short warm-up run, then
   ``--reps`` measured runs of ``--duration`` s each;
2. the query data set (20 entities x 1 day at one sample per minute, tenant
   ``benchquery``) POSTed over HTTP to the target's /v2/notify -- so an
   external service is loaded exactly like ours -- and checked (skipped with
   ``--no-load`` for a service loaded before);
3. lastN=100 on one entity attribute at 8 and 1 connections; the type-level
   hourly average over the day (20 entities) at 8 and 1 connections;
   ``/v2/types/Lawnmower/attrs/{attr}?lastN=1000`` at 1 connection;
4. ours only: stops it and checks the store holds every acknowledged
   notification (and nothing twice); then ``geo.py`` (near + lastN=10 over
   10k moving entities at 4 connections, run once per backend: it loads 1M
   positions first).

The bare ceiling (``bare_app.py``) gets the same ingest load and a GET of a
ready lastN=100 answer at 8 and 1 connections (the "bare GET ceiling"); so
does the raw ASGI ceiling (``bare_app.raw_app``, no framework), which issue
30 holds our lastN=100 at 8 connections against (>= 0.3 on DuckDB, >= 0.15
on PostgreSQL).

Load comes from wrk (``wrkrun.py``: Lua-generated unique POST bodies),
installed with apt-get when missing and root; ``--loadgen`` (or no wrk)
uses ``loadgen.py`` instead. Every figure is printed as median [min-max]
over the reps. Every "x QuantumLeap" figure (in the table and in the
targets) divides by QuantumLeap measured in the same run: a target named
``ql`` or ``quantumleap`` given with ``--url``. Without one, no ratio to
QuantumLeap is printed and its targets are left out: this file keeps no
stored QuantumLeap figure, and the README and docs quote only ratios it
printed. QuantumLeap 1.0.1 is set up from its own source and lock file
(PostgreSQL + PostGIS, 2 gunicorn workers, no Docker) by the scripts in
``../shared/ql-sidebyside/``; once it serves on 127.0.0.1:8669::

    .venv/bin/python benchmarks/compare.py --url ql=http://127.0.0.1:8669

The load average before and after each target is in the output: the
machine must be idle, and only ratios measured in one run count.

``--json FILE`` writes every raw figure. Exit status: 0 when everything ran
(targets may FAIL: they are in the table), 1 when a step failed, and with
``--strict`` also when a target fails.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shutil
import subprocess
import sys
import tempfile
import time
import urllib.error
import urllib.request
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import UTC, datetime
from functools import partial
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import common
import lawnmower
import wrkrun
from common import HERE, Server, bare_cmd, free_port, ours_cmd, raw_cmd, spawned
from loads import POOL, Runner, get_load, ingest_load, summary

INGEST = [("ingest16", 16), ("ingest64", 64)]
QUERIES = [
    ("lastN8", "lastN", 8),
    ("lastN1", "lastN", 1),
    ("hourly8", "hourly_avg", 8),
    ("hourly1", "hourly_avg", 1),
    ("types1", "type_lastN", 1),
]
BARE_GETS = [("lastN8", 8), ("lastN1", 1)]
LABELS = {
    "ingest16": "ingest, 16 connections",
    "ingest64": "ingest, 64 connections",
    "lastN8": "lastN=100, 8 connections",
    "lastN1": "lastN=100, 1 connection",
    "hourly8": "hourly avg, type level (20 entities), 8 connections",
    "hourly1": "hourly avg, type level, 1 connection",
    "types1": "/v2/types/{type}/attrs/{attr}?lastN=1000, 1 connection",
    "geo4": "geo near;maxDistance + lastN=10, 10k entities, 4 connections",
}
# (backend, workers, ingest processes)
OURS = {
    "duckdb": ("duckdb", 1, 1),
    "duckdb2": ("duckdb", 1, 2),
    "duckdb3": ("duckdb", 1, 3),
    "postgresql": ("postgresql", 1, 1),
    "postgresql2": ("postgresql", 2, 1),
}


# --- measuring ---------------------------------------------------------------------------


def stored_notifications(db: str, run_ids: list[str]) -> tuple[int, int]:
    """(stored notifications, distinct ones) of the ingest runs, read from
    the store after the server stopped: one batteryLevel sample each."""
    prefixes = [f"urn:ngsi-ld:Lawnmower:{r}-" for r in run_ids]
    where = "s.tenant = {p} AND s.attr = 'batteryLevel' AND regexp_replace(s.entity_id, '-[0-9]+$', '-') = ANY({p})"
    sql = (
        "SELECT count(*), count(DISTINCT (s.entity_id, a.num)) FROM series s JOIN samples_all a "
        "ON a.sid = s.sid WHERE " + where
    )
    if db.startswith("postgresql://"):
        import psycopg

        with psycopg.connect(db) as conn:
            return conn.execute(sql.format(p="%s"), [lawnmower.INGEST_TENANT, prefixes]).fetchone()
    import duckdb

    con = duckdb.connect(db, read_only=True)
    try:
        return con.execute(sql.format(p="?"), [lawnmower.INGEST_TENANT, prefixes]).fetchone()
    finally:
        con.close()


def check_store(db: str, run_ids: list[str], runs: list[dict]) -> dict:
    """Every acknowledged notification stored, none twice. wrk stops with
    requests in flight (sent, maybe stored, never counted): up to one per
    connection per run may be stored beyond the acknowledged ones."""
    acked = sum(r["ok"] for r in runs) + 1  # + the sanity notification
    slack = sum(r["non_2xx"] + r["errors"] + r["connections"] for r in runs)
    stored, distinct = stored_notifications(db, run_ids)
    return {
        "acknowledged": acked,
        "stored": stored,
        "distinct": distinct,
        "lost": max(0, acked - stored),
        "ok": acked <= stored <= acked + slack and distinct == stored,
    }


# --- one target -------------------------------------------------------------------------


@dataclass
class Result:
    name: str
    kind: str  # ours, bare, raw, external
    backend: str | None = None
    workers: int = 1
    runs: dict[str, list[dict]] = field(default_factory=dict)
    info: dict = field(default_factory=dict)

    def get(self, scenario: str, key: str) -> float | None:
        s = summary(self.runs.get(scenario, []), key)
        return None if s is None else s["median"]


def post_one(url: str, body: bytes) -> None:
    req = urllib.request.Request(
        url + "/v2/notify", data=body, method="POST", headers=lawnmower.headers(lawnmower.INGEST_TENANT)
    )
    with urllib.request.urlopen(req, timeout=30) as resp:
        if not 200 <= resp.status < 300:
            raise RuntimeError(f"sanity notification answered {resp.status}")


def measure_target(
    result: Result,
    url: str,
    runner: Runner,
    only: set[str],
    load: bool,
    server: Server | None = None,
    settle: Callable[[], float] | None = None,
) -> list[str]:
    """Ingest and query scenarios against ``url``; returns the run ids used.
    ``settle()``: run after the query data set is loaded, before it is
    queried (returns seconds taken)."""
    run_id = f"{int(time.time()) % 10**6}{os.getpid() % 100:02d}"
    ledger: list[str] = []
    cpu0 = server.cpu_seconds() if server else math.nan
    if "ingest" in only:
        post_one(url, lawnmower.ingest_body(f"{run_id}s", 0, POOL))
        ledger.append(f"{run_id}s")
        for key, conns in INGEST:
            print(f"  {LABELS[key]} ...", flush=True)
            result.runs[key] = runner.repeat(url, ingest_load(url, f"{run_id}{key[6:]}", ledger), conns)
            _print_runs(result.runs[key])
    if "queries" in only and result.kind in ("bare", "raw"):
        path = "/v2/entities/urn:ngsi-ld:Lawnmower:q00/attrs/batteryLevel?lastN=100"
        for key, conns in BARE_GETS:
            print(f"  bare GET ceiling, {conns} connection(s) ...", flush=True)
            result.runs[key] = runner.repeat(url, get_load(url, [path], lawnmower.query_headers()), conns)
            _print_runs(result.runs[key])
    elif "queries" in only:
        if load:
            print("  loading the query data set over HTTP ...", flush=True)
            result.info["dataset_load"] = lawnmower.load_dataset(url)
            print(f"    {result.info['dataset_load']}", flush=True)
            if settle is not None:
                result.info["settle_s"] = round(settle(), 2)
                print(f"    settled in {result.info['settle_s']} s", flush=True)
        result.info["dataset_check"] = lawnmower.check_dataset(url)
        paths = lawnmower.query_paths()
        for key, scenario, conns in QUERIES:
            print(f"  {LABELS[key]} ...", flush=True)
            result.runs[key] = runner.repeat(url, get_load(url, paths[scenario], lawnmower.query_headers()), conns)
            _print_runs(result.runs[key])
    if server is not None:
        result.info["server_cpu_s"] = round(server.cpu_seconds() - cpu0, 1)
        result.info["rss_mib"] = round((server.rss_bytes() or 0) / 2**20)
    return ledger


def _print_runs(runs: list[dict]) -> None:
    for r in runs:
        if r.get("warmup"):
            continue
        print(
            f"    {r['rps']:9,.0f}/s  p50 {r['p50_ms']:7.2f} ms  p99 {r['p99_ms']:8.2f} ms  "
            f"non-2xx {r['non_2xx']}  errors {r['errors']}  (load {common.loadavg(None)[0]:.1f})",
            flush=True,
        )


def run_ours(key: str, runner: Runner, only: set[str], workdir: Path, env: dict[str, str]) -> Result:
    backend, workers, ingest_processes = OURS[key]
    name = {
        "duckdb": "ours, DuckDB",
        "duckdb2": "ours, DuckDB (2 ingest processes)",
        "duckdb3": "ours, DuckDB (3 ingest processes)",
        "postgresql": "ours, PostgreSQL",
        "postgresql2": "ours, PostgreSQL (2 workers)",
    }[key]
    result = Result(name, "ours", backend, workers)
    cluster = None
    try:
        if backend == "postgresql":
            from pgutil import BenchCluster

            cluster = BenchCluster(f"cmp{key}").start()
            db = cluster.url
            result.info["postgresql"] = cluster.version
        else:
            db = str(workdir / f"{key}.duckdb")
        port = free_port()
        server = spawned(key, ours_cmd(db, port, workers, ingest_processes), port, workdir, env)
        server.start()
        result.info["startup_s"] = round(server.startup_s, 2)
        print(f"- {name} on :{port}, started in {server.startup_s:.1f} s (load {_load()})", flush=True)
        try:
            settle = partial(vacuum_analyze, db) if backend == "postgresql" else None
            ledger = measure_target(result, server.url, runner, only, load=True, server=server, settle=settle)
        finally:
            result.info["exit_code"] = server.stop()
        if "ingest" in only:
            all_runs = [r for k, _ in INGEST for r in result.runs[k]]  # warm-ups included: they stored too
            result.info["store_check"] = check_store(db, ledger, all_runs)
            print(f"  store check: {result.info['store_check']}", flush=True)
        if "geo" in only and workers == 1 and ingest_processes == 1:
            result.runs["geo4"] = run_geo(backend, runner, workdir)
    finally:
        if cluster is not None:
            cluster.stop()
    return result


def vacuum_analyze(db: str) -> float:
    """``VACUUM (ANALYZE)`` of our PostgreSQL database: the state autovacuum
    reaches about a minute after a bulk load (migration 0007 lowers its
    insert threshold to 2 %), measured at once. Before it, the planner sees
    none of the 144,000 new rows (it sorts 28,800 of them where it would
    hash) and the visibility map is empty (no index-only scan): the hourly
    average takes 24 ms instead of 12, and which of the two a run measured
    depended on autovacuum's timing."""
    import psycopg

    started = time.perf_counter()
    with psycopg.connect(db, autocommit=True) as conn:
        conn.execute("VACUUM (ANALYZE)")
    return time.perf_counter() - started


def run_geo(backend: str, runner: Runner, workdir: Path) -> list[dict]:
    """benchmarks/geo.py as it is (another module owns its semantics), once."""
    out = workdir / f"geo-{backend}.json"
    cmd = [
        sys.executable,
        str(HERE / "geo.py"),
        "--backend",
        backend,
        "--connections",
        "4",
        "--duration",
        str(runner.duration),
        "--warmup",
        str(max(runner.warmup, 1.0)),
        "--json",
        str(out),
    ]
    print(f"  geo.py --backend {backend} (loads 10k entities x 100 positions first) ...", flush=True)
    proc = subprocess.run(cmd, capture_output=True, text=True)
    (workdir / f"geo-{backend}.log").write_text(proc.stdout + proc.stderr)
    if not out.exists():
        print(f"    geo.py failed ({proc.returncode}); see {workdir / f'geo-{backend}.log'}", flush=True)
        return []
    doc = json.loads(out.read_text())
    loaded = doc["results"]["loaded"]
    run = {k: loaded.get(k) for k in ("rps", "p50_ms", "p99_ms", "non_2xx", "errors")}
    run["connections"] = loaded.get("connections")
    print(f"    {run['rps']:.1f}/s  p50 {run['p50_ms']:.2f} ms", flush=True)
    return [run]


def run_bare(runner: Runner, only: set[str], workdir: Path, kind: str = "bare") -> Result:
    """A ceiling: the bare FastAPI app, or (``kind`` raw) the raw ASGI one."""
    name, cmd = ("bare FastAPI", bare_cmd) if kind == "bare" else ("raw ASGI", raw_cmd)
    result = Result(f"{name} (ceiling)", kind)
    port = free_port()
    server = spawned(kind, cmd(port), port, workdir)
    server.start()
    print(f"- {name} on :{port} (load {_load()})", flush=True)
    try:
        measure_target(result, server.url, runner, only - {"geo"}, load=False, server=server)
    finally:
        server.stop()
    return result


def run_external(name: str, url: str, runner: Runner, only: set[str], load: bool) -> Result:
    result = Result(name, "external")
    print(f"- {name} at {url} (load {_load()})", flush=True)
    measure_target(result, url.rstrip("/"), runner, only - {"geo"}, load=load)
    return result


def _load() -> str:
    return common.load_text()


# --- the tables ---------------------------------------------------------------------------


def cell(runs: list[dict] | None, key: str, digits: int = 0) -> str:
    return common.spread_text((r.get(key) for r in runs or [] if not r.get("warmup")), digits, thousands=True)


def ql_figures(results: list[Result]) -> tuple[dict, str]:
    """QuantumLeap's figures, measured in this run (a target named ql or
    quantumleap); none without one: no ratio is computed against a stored
    figure."""
    for r in results:
        if r.kind == "external" and r.name.lower() in ("ql", "quantumleap"):
            return (
                {
                    k: {"rps": r.get(k, "rps"), "p50_ms": r.get(k, "p50_ms"), "p99_ms": r.get(k, "p99_ms")}
                    for k in r.runs
                },
                f"measured in this run ({r.name})",
            )
    return {}, "not measured in this run (no --url ql=...): no ratio to QuantumLeap"


def print_comparison(results: list[Result]) -> None:
    ql, source = ql_figures(results)
    cols = [r for r in results]
    print("\n" + "=" * 100)
    print("median [min-max] over the reps; rates are 2xx answers/s, latencies ms")
    print(f"QuantumLeap: {source}")
    header = ["", "QuantumLeap"] + [r.name for r in cols]
    rows = []
    for key in [k for k, _ in INGEST] + [k for k, _, _ in QUERIES] + ["geo4"]:
        if not any(key in r.runs for r in cols):
            continue
        q = ql.get(key, {})
        qtext = (
            " ".join(
                x
                for x in (
                    f"{q['rps']:,.0f}/s" if q.get("rps") else "",
                    f"p50 {q['p50_ms']:.1f}" if q.get("p50_ms") else "",
                    f"p99 {q['p99_ms']:.0f}" if q.get("p99_ms") else "",
                )
                if x
            )
            or "-"
        )
        rows.append([LABELS[key] + ": req/s", qtext] + [cell(r.runs.get(key), "rps") for r in cols])
        rows.append(["  p50 ms", ""] + [cell(r.runs.get(key), "p50_ms", 2) for r in cols])
        rows.append(["  p99 ms", ""] + [cell(r.runs.get(key), "p99_ms", 1) for r in cols])
        if q.get("rps"):
            rows.append(
                ["  vs QuantumLeap (rate)", "1"]
                + [
                    f"{r.get(key, 'rps') / q['rps']:.1f}x" if r.kind == "ours" and r.get(key, "rps") else ""
                    for r in cols
                ]
            )
    rows.append(["start-up s", ""] + [str(r.info.get("startup_s", "")) for r in cols])
    rows.append(["server RSS MiB (end)", ""] + [str(r.info.get("rss_mib", "")) for r in cols])
    rows.append(
        ["store check (lost / acknowledged)", ""]
        + [
            (
                f"{r.info['store_check']['lost']} / {r.info['store_check']['acknowledged']:,}"
                + ("" if r.info["store_check"]["ok"] else " FAIL")
            )
            if "store_check" in r.info
            else ""
            for r in cols
        ]
    )
    common.print_rows(header, rows)


def targets(results: list[Result]) -> list[dict]:
    """Issue 15's targets per backend, on the medians."""
    ql, _ = ql_figures(results)
    bare = next((r for r in results if r.kind == "bare"), None)
    raw = next((r for r in results if r.kind == "raw"), None)
    out = []

    def add(target: str, result: Result, value, ok) -> None:
        out.append({"target": target, "who": result.name, "value": value, "pass": ok})

    for r in (x for x in results if x.kind == "ours"):
        for key, _ in INGEST:
            rps, q = r.get(key, "rps"), ql.get(key, {}).get("rps")
            if rps is not None and q:
                add(f"{LABELS[key]}: >= 10x QuantumLeap ({10 * q:,.0f}/s)", r, f"{rps / q:.1f}x", rps >= 10 * q)
        shares = (0.6, 0.8) if r.backend == "duckdb" else (0.5, 0.7)  # issue 30's
        for key, want in zip(("ingest16", "ingest64"), shares, strict=True):
            rps, b = r.get(key, "rps"), bare.get(key, "rps") if bare else None
            if rps is not None and b:
                add(f"{LABELS[key]}: >= {want} of the bare ceiling", r, f"{rps / b:.2f}", rps >= want * b)
        p99 = r.get("ingest64", "p99_ms")
        if p99 is not None:
            add("ingest, 64 connections: p99 <= 50 ms", r, f"{p99:.1f} ms", p99 <= 50)
        if "store_check" in r.info:
            c = r.info["store_check"]
            errs = sum(x["non_2xx"] + x["errors"] for k, _ in INGEST for x in r.runs.get(k, []) if not x.get("warmup"))
            add("ingest: 0 lost, 0 refused", r, f"{c['lost']} lost, {errs} refused", c["ok"] and errs == 0)
        want = 15 if r.backend == "duckdb" else 5
        rps, q = r.get("lastN8", "rps"), ql.get("lastN8", {}).get("rps")
        if rps is not None and q:
            add(f"lastN=100, 8 connections: >= {want}x QuantumLeap", r, f"{rps / q:.1f}x", rps >= want * q)
        want = 0.3 if r.backend == "duckdb" else 0.15
        rps, ceiling = r.get("lastN8", "rps"), raw.get("lastN8", "rps") if raw else None
        if rps is not None and ceiling:
            add(
                f"lastN=100, 8 connections: >= {want} of the raw ASGI GET",
                r,
                f"{rps / ceiling:.2f}",
                rps >= want * ceiling,
            )
        agg, last = r.get("hourly1", "p50_ms"), r.get("lastN1", "p50_ms")
        if agg is not None and last:
            add("hourly avg p50 <= 3x lastN=100 p50 (1 connection)", r, f"{agg / last:.1f}x", agg <= 3 * last)
        want = 30 if r.backend == "duckdb" else 10
        rps, q = r.get("hourly8", "rps"), ql.get("hourly8", {}).get("rps")
        if rps is not None and q:
            add(f"hourly avg, 8 connections: >= {want}x QuantumLeap", r, f"{rps / q:.1f}x", rps >= want * q)
        p50 = r.get("types1", "p50_ms")
        if p50 is not None:
            add("types lastN=1000: p50 <= 30 ms", r, f"{p50:.1f} ms", p50 <= 30)
        p50 = r.get("geo4", "p50_ms")
        if p50 is not None:
            add("geo near + lastN=10, 4 connections: p50 <= 30 ms", r, f"{p50:.1f} ms", p50 <= 30)
    return out


def print_targets(rows: list[dict]) -> None:
    if not rows:
        return
    print("\ntargets (issues 15 and 30), on the medians:")
    common.print_rows(
        ["target", "who", "measured", "result"],
        [[t["target"], t["who"], t["value"], "PASS" if t["pass"] else "FAIL"] for t in rows],
    )


# --- main ----------------------------------------------------------------------------------


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument(
        "--url",
        action="append",
        default=[],
        metavar="NAME=URL",
        help="a running service to measure too (repeatable); name ql or quantumleap makes it the reference",
    )
    ap.add_argument("--no-load", action="store_true", help="do not POST the query data set to --url services")
    ap.add_argument(
        "--ours",
        default="duckdb,postgresql,postgresql2",
        help="our configurations: duckdb, postgresql, postgresql2 (2 workers), or none",
    )
    ap.add_argument("--no-bare", action="store_true", help="leave the ceilings (bare FastAPI, raw ASGI) out")
    ap.add_argument(
        "--only",
        default="ingest,queries,geo",
        help="comma list of ingest, queries, geo, growth (default: all but growth)",
    )
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--duration", type=float, default=10.0, help="seconds per measured run")
    ap.add_argument("--warmup", type=float, default=2.0, help="seconds of the warm-up run before each scenario")
    ap.add_argument("--quick", action="store_true", help="1 rep, 3 s runs, 1 s warm-up, no geo")
    ap.add_argument("--loadgen", action="store_true", help="use loadgen.py instead of wrk")
    ap.add_argument("--sizes", default="1M,10M,100M", help="growth curve sizes (with --only growth)")
    ap.add_argument("--growth-backends", default="duckdb", help="growth curve backends: duckdb,postgresql")
    ap.add_argument(
        "--server-env",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="settings for our servers (e.g. TSDB_WRITER_THREADS=2); TSDB_* of this shell are not passed",
    )
    ap.add_argument("--json", type=Path, help="write every raw figure here")
    ap.add_argument("--keep", action="store_true", help="keep the work dir (databases, logs)")
    ap.add_argument("--strict", action="store_true", help="exit 1 when a target fails")
    args = ap.parse_args(argv)
    server_env = dict(item.split("=", 1) for item in args.server_env)
    only = {x.strip() for x in args.only.split(",") if x.strip()}
    if args.quick:
        args.reps, args.duration, args.warmup = 1, 3.0, 1.0
        if args.only == ap.get_default("only"):
            only.discard("geo")
    use_wrk = not args.loadgen and wrkrun.ensure_wrk() is not None
    runner = Runner(args.reps, args.duration, args.warmup, use_wrk)
    ours = [] if args.ours == "none" else [x.strip() for x in args.ours.split(",") if x.strip()]
    if set(ours) - OURS.keys():
        ap.error(f"--ours takes {', '.join(OURS)} or none")
    workdir = Path(tempfile.mkdtemp(prefix="tsdb-compare-"))
    speed = {"start": common.speed_probe(workdir)}
    print(
        f"compare: {os.cpu_count()} CPUs, load {_load()}, {common.speed_text(speed['start'])}, "
        f"{'wrk' if use_wrk else 'loadgen.py'}, "
        f"{runner.reps} reps x {runner.duration:g} s (+ {runner.warmup:g} s warm-up); work dir {workdir}",
        flush=True,
    )
    results: list[Result] = []
    failed: list[str] = []
    doc: dict = {
        "started_at": datetime.now(UTC).isoformat(timespec="seconds"),
        "machine": common.machine(),
        "config": {**vars(args), "json": str(args.json), "generator": "wrk" if use_wrk else "loadgen"},
        "loadavg": {"start": common.loadavg(None)},
        "speed": speed,
    }
    steps = []
    if only - {"growth"}:
        named = [
            u.split("=", 1) if "=" in u.split("://", 1)[0] else (f"service {i + 1}", u) for i, u in enumerate(args.url)
        ]
        steps += [(f"url:{u}", lambda n=n, u=u: run_external(n, u, runner, only, not args.no_load)) for n, u in named]
        steps += [(f"ours:{k}", lambda k=k: run_ours(k, runner, only, workdir, server_env)) for k in ours]
        if not args.no_bare and only & {"ingest", "queries"}:
            steps.append(("bare", lambda: run_bare(runner, only, workdir)))
            steps.append(("raw", lambda: run_bare(runner, only, workdir, "raw")))
    for name, step in steps:
        before = common.loadavg(None)
        try:
            result = step()
            result.info["loadavg_before"], result.info["loadavg_after"] = before, common.loadavg(None)
            results.append(result)
        except Exception as exc:  # report and go on with the next target
            print(f"  {name} FAILED: {exc}", flush=True)
            failed.append(f"{name}: {exc}")
    if results:
        print_comparison(results)
        doc["targets"] = target_rows = targets(results)
        print_targets(target_rows)
    if "growth" in only:
        import growth

        doc["growth"] = growth.run(args.sizes, args.growth_backends, runner, workdir)
    doc["results"] = [r.__dict__ for r in results]
    doc["failed"] = failed
    doc["loadavg"]["end"] = common.loadavg(None)
    speed["end"] = common.speed_probe(workdir)
    print(
        f"\nload average at the end: {_load()}; {common.speed_text(speed['end'])} "
        f"(at the start: {common.speed_text(speed['start'])})"
    )
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        common.write_json(args.json, doc)
        print(f"results written to {args.json}")
    if args.keep:
        print(f"kept {workdir}")
    else:
        shutil.rmtree(workdir, ignore_errors=True)
    if failed:
        print("FAILED: " + "; ".join(failed), file=sys.stderr)
        return 1
    if args.strict and any(not t["pass"] for t in doc.get("targets", [])):
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
