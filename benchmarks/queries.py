"""History query benchmark: latency and throughput of the read API.

    .venv/bin/python benchmarks/queries.py [--duration 10] [--connections 8] [--json FILE]

1. Loads 10,000,000 samples (1,000 entities x 10 attributes x 1,000
   samples, one notification every 90 s per entity) in-process through the
   store (``write_sync`` with big ``AppendSamples`` batches), compacts it
   (``compact(full=True)``) and closes it. ``--db FILE`` reuses a loaded file.
2. Starts the real server (``tsdb-service serve``) on that file.
3. Drives it with ``benchmarks/loadgen.py`` (closed loop, keep-alive,
   ``--connections`` connections, random entity per request):
   a. ``/v2/entities/{id}/attrs/{attr}?lastN=100``
   b. ``/v2/entities/{id}/attrs/{attr}?aggrMethod=avg&aggrPeriod=hour`` over one day
   c. ``/v2/types/{type}/attrs/{attr}?lastN=1000``
4. Prints p50/p99 latency, requests/s, server RSS and bytes on disk per
   stored sample, with PASS/FAIL against the targets (lastN p50 <= 5 ms and
   >= 2,000 req/s; hourly aggregation p50 <= 20 ms). Exit status 0 = all pass.
"""

from __future__ import annotations

import argparse
import json
import os
import random
import shutil
import signal
import subprocess
import sys
import tempfile
import time
import urllib.request
from datetime import UTC, datetime, timedelta
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(ROOT))

from loadgen import build_request, run_load  # noqa: E402

import psutil  # noqa: E402

HOST = "127.0.0.1"
ENTITIES = 1_000
ATTRS = 10
SAMPLES = 1_000
STEP = timedelta(seconds=90)
START = datetime(2024, 5, 1, tzinfo=UTC)
ENTITY_TYPE = "Robot"


def entity_id(n: int) -> str:
    return f"urn:ngsi-ld:Robot:{n:04d}"


def attr_name(n: int) -> str:
    return f"attr{n}"


# --- 1. load ---------------------------------------------------------------------------


def load(db: Path, batch_notifications: int = 20_000) -> dict:
    from tsdb_service.model import AttrSample, EntitySample, Kind
    from tsdb_service.storage.base import AppendSamples
    from tsdb_service.storage.duckdb_store import DuckDBStore

    t0 = time.perf_counter()
    store = DuckDBStore(str(db))
    names = [attr_name(a) for a in range(ATTRS)]
    ids = [entity_id(e) for e in range(ENTITIES)]
    rng = random.Random(42)
    batch: list[EntitySample] = []
    written = 0
    try:
        for i in range(SAMPLES):
            moment = START + i * STEP
            for e in range(ENTITIES):
                base = e + i * 0.01
                attrs = [
                    AttrSample(names[a], "Number", Kind.NUMBER, num=base + a + rng.random()) for a in range(ATTRS)
                ]
                batch.append(EntitySample("", "/", ids[e], ENTITY_TYPE, moment, attrs))
                if len(batch) >= batch_notifications:
                    store.write_sync([AppendSamples(batch)])
                    written += len(batch) * ATTRS
                    batch = []
            if i % 100 == 99:
                print(f"  loaded {written:,} samples ({time.perf_counter() - t0:.0f} s)", flush=True)
        if batch:
            store.write_sync([AppendSamples(batch)])
            written += len(batch) * ATTRS
        t_load = time.perf_counter() - t0
        store.compact(full=True)
        t_compact = time.perf_counter() - t0 - t_load
    finally:
        store.close()
    return {"samples": written, "load_s": round(t_load, 1), "compact_s": round(t_compact, 1)}


def engine_ceiling(db: Path, seconds: float = 4.0, threads: int = 2) -> dict:
    """The lastN=100 query alone, in-process, with no HTTP: what DuckDB can do
    on this machine, for comparison with the served rate."""
    import threading

    from tsdb_service.history.params import history_query
    from tsdb_service.history.query import Shape
    from tsdb_service.storage.duckdb_store import DuckDBStore

    store = DuckDBStore(str(db))
    querier = store.querier()
    counts = []

    def worker(seed: int) -> None:
        rng = random.Random(seed)
        n = 0
        end = time.perf_counter() + seconds
        while time.perf_counter() < end:
            query = history_query(Shape.ENTITY_ATTR, {"lastN": "100"}, {}, "", 10_000,
                                  entity_id=entity_id(rng.randrange(ENTITIES)), attr=attr_name(rng.randrange(ATTRS)))
            refs = querier.series(query.scope, query.entities, {query.attrs[0].attr})
            querier.raw_rows([r.sid for r in refs], query.time, newest_first=True, limit=100, offset=0,
                             one_per_row=True)
            n += 1
        counts.append(n)

    try:
        worker(0)  # warm up
        counts.clear()
        cpu0 = time.process_time()
        pool = [threading.Thread(target=worker, args=(i,)) for i in range(threads)]
        for t in pool:
            t.start()
        for t in pool:
            t.join()
        cpu = time.process_time() - cpu0
    finally:
        store.close()
    total = sum(counts)
    return {"queries_per_s": total / seconds, "cpu_ms_per_query": cpu / max(total, 1) * 1e3, "threads": threads}


# --- 2. server ---------------------------------------------------------------------------


def free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind((HOST, 0))
        return s.getsockname()[1]


def start_server(db: Path, port: int, log_path: Path) -> subprocess.Popen:
    exe = ROOT / ".venv" / "bin" / "tsdb-service"
    cmd = [str(exe), "serve", "--db", str(db), "--host", HOST, "--port", str(port)]
    env = {k: v for k, v in os.environ.items() if not k.startswith("TSDB_")}
    log = open(log_path, "wb")
    proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, env=env,
                            start_new_session=True)
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise RuntimeError(f"server exited ({proc.returncode}); see {log_path}")
        try:
            with urllib.request.urlopen(f"http://{HOST}:{port}/health", timeout=2) as r:
                if r.status == 200:
                    return proc
        except OSError:
            pass
        time.sleep(0.1)
    proc.kill()
    raise RuntimeError(f"server not healthy in time; see {log_path}")


def stop_server(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(60)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def get(port: int, path: str) -> tuple[int, bytes]:
    try:
        with urllib.request.urlopen(f"http://{HOST}:{port}{path}", timeout=30) as r:
            return r.status, r.read()
    except urllib.error.HTTPError as exc:
        return exc.code, exc.read()


# --- 3. load generation ---------------------------------------------------------------------


def scenarios(port: int) -> dict[str, list[bytes]]:
    rng = random.Random(7)
    day_from = START.strftime("%Y-%m-%dT%H:%M:%SZ")
    day_to = (START + timedelta(days=1) - timedelta(seconds=1)).strftime("%Y-%m-%dT%H:%M:%SZ")
    out: dict[str, list[bytes]] = {"lastN": [], "hourly_avg": [], "type_lastN": []}
    for _ in range(4096):
        e, a = rng.randrange(ENTITIES), rng.randrange(ATTRS)
        out["lastN"].append(build_request("GET", f"/v2/entities/{entity_id(e)}/attrs/{attr_name(a)}?lastN=100",
                                          HOST, port))
        out["hourly_avg"].append(build_request(
            "GET",
            f"/v2/entities/{entity_id(e)}/attrs/{attr_name(a)}?aggrMethod=avg&aggrPeriod=hour"
            f"&fromDate={day_from}&toDate={day_to}",
            HOST, port))
    for a in range(ATTRS):
        out["type_lastN"].append(build_request("GET", f"/v2/types/{ENTITY_TYPE}/attrs/{attr_name(a)}?lastN=1000",
                                               HOST, port))
    return out


def check_answers(port: int) -> None:
    """The requests we measure must answer what we loaded."""
    e, a = 17, 3
    status, body = get(port, f"/v2/entities/{entity_id(e)}/attrs/{attr_name(a)}?lastN=100")
    doc = json.loads(body)
    assert status == 200 and len(doc["values"]) == 100, (status, body[:300])
    assert doc["index"][-1] == (START + (SAMPLES - 1) * STEP).strftime("%Y-%m-%dT%H:%M:%S.000+00:00"), doc["index"][-1]
    status, body = get(port, f"/v2/entities/{entity_id(e)}/attrs/{attr_name(a)}?aggrMethod=avg&aggrPeriod=hour"
                             f"&fromDate=2024-05-01T00:00:00Z&toDate=2024-05-01T23:59:59Z")
    doc = json.loads(body)
    assert status == 200 and len(doc["values"]) == 24, (status, body[:300])
    status, body = get(port, f"/v2/types/{ENTITY_TYPE}/attrs/{attr_name(a)}?lastN=1000")
    doc = json.loads(body)
    assert status == 200 and sum(len(x["values"]) for x in doc["entities"]) == 1000, (status, body[:300])


def measure(port: int, requests: list[bytes], connections: int, duration: float, warmup: float):
    n = len(requests)
    return run_load(HOST, port, lambda seq: requests[seq % n], connections=connections, duration=duration,
                    warmup=warmup)


# --- 4. report -------------------------------------------------------------------------------


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--db", help="reuse this loaded DuckDB file (default: load a fresh one in a temp dir)")
    ap.add_argument("--keep", action="store_true", help="keep the temporary database")
    ap.add_argument("--duration", type=float, default=10.0)
    ap.add_argument("--warmup", type=float, default=2.0)
    ap.add_argument("--connections", type=int, default=8)
    ap.add_argument("--type-connections", type=int, default=2, help="connections for the /v2/types scenario")
    ap.add_argument("--json", help="write the results here")
    args = ap.parse_args(argv)

    tmp = None
    if args.db:
        db = Path(args.db)
        loaded = {"samples": ENTITIES * ATTRS * SAMPLES, "reused": str(db)}
        if not db.exists():
            print(f"loading {ENTITIES * ATTRS * SAMPLES:,} samples into {db} ...", flush=True)
            loaded = load(db)
    else:
        tmp = Path(tempfile.mkdtemp(prefix="tsdb-queries-"))
        db = tmp / "bench.duckdb"
        print(f"loading {ENTITIES * ATTRS * SAMPLES:,} samples into {db} ...", flush=True)
        loaded = load(db)
    print(f"  {loaded}", flush=True)
    disk = db.stat().st_size + (Path(str(db) + ".wal").stat().st_size if Path(str(db) + ".wal").exists() else 0)
    samples = ENTITIES * ATTRS * SAMPLES

    print("measuring the engine alone (same lastN query in-process, no HTTP) ...", flush=True)
    ceiling = engine_ceiling(db)
    print(f"  {ceiling}", flush=True)

    port = free_port()
    log_path = (tmp or db.parent) / "server.log"
    proc = start_server(db, port, log_path)
    results: dict[str, dict] = {}
    try:
        check_answers(port)
        server = psutil.Process(proc.pid)
        reqs = scenarios(port)
        plan = [
            ("lastN", "lastN", "lastN=100, one entity attribute", args.connections),
            ("hourly_avg", "hourly_avg", "avg per hour over one day, one entity attribute", args.connections),
            ("type_lastN", "type_lastN", "/v2/types/{type}/attrs/{attr}?lastN=1000", args.type_connections),
            ("lastN_1conn", "lastN", "lastN=100, unloaded (1 connection)", 1),
            ("hourly_avg_1conn", "hourly_avg", "avg per hour, unloaded (1 connection)", 1),
        ]
        rss_peak = server.memory_info().rss
        for key, scenario, label, conns in plan:
            duration = args.duration if key != "type_lastN" else max(5.0, args.duration / 2)
            print(f"measuring {label} ({conns} connections, {duration:g} s) ...", flush=True)
            cpu0 = server.cpu_times()
            stats = measure(port, reqs[scenario], conns, duration, args.warmup)
            cpu1 = server.cpu_times()
            rss_peak = max(rss_peak, server.memory_info().rss)
            cpu_ms = (cpu1.user + cpu1.system - cpu0.user - cpu0.system) / max(stats.total_ok, 1) * 1e3
            results[key] = {"label": label, "connections": conns, "server_cpu_ms_per_req": cpu_ms,
                            **stats.to_dict()}
        rss_end = server.memory_info().rss
    finally:
        stop_server(proc)

    a, b, c = results["lastN"], results["hourly_avg"], results["type_lastN"]
    checks = {
        "lastN p50 <= 5 ms": a["p50_ms"] is not None and a["p50_ms"] <= 5.0,
        "lastN >= 2000 req/s": a["rps"] >= 2000,
        "hourly avg p50 <= 20 ms": b["p50_ms"] is not None and b["p50_ms"] <= 20.0,
        "no errors": all(r["errors"] == 0 and r["non_2xx"] == 0 for r in results.values()),
    }
    print()
    print(f"{'scenario':<48} {'conns':>5} {'req/s':>8} {'p50 ms':>8} {'p99 ms':>8} {'cpu ms/req':>10} {'errors':>6}")
    for r in results.values():
        print(f"{r['label']:<48} {r['connections']:>5} {r['rps']:>8.0f} {r['p50_ms']:>8.2f} {r['p99_ms']:>8.2f} "
              f"{r['server_cpu_ms_per_req']:>10.2f} {r['errors'] + r['non_2xx']:>6}")
    print(f"{'engine alone: lastN=100 in-process, 2 threads':<48} {'-':>5} {ceiling['queries_per_s']:>8.0f} "
          f"{'-':>8} {'-':>8} {ceiling['cpu_ms_per_query']:>10.2f}")
    print()
    print(f"server RSS: {rss_end / 2**20:.0f} MiB (peak seen {rss_peak / 2**20:.0f} MiB)")
    print(f"on disk: {disk / 2**20:.0f} MiB for {samples:,} samples = {disk / samples:.1f} bytes/sample")
    print()
    for name, ok in checks.items():
        print(f"{'PASS' if ok else 'FAIL'}  {name}")
    report = {
        "load": loaded, "results": results, "rss_bytes": rss_end, "rss_peak_bytes": rss_peak,
        "disk_bytes": disk, "bytes_per_sample": disk / samples, "checks": checks, "engine_alone": ceiling,
        "machine": {"cpus": os.cpu_count()},
    }
    if args.json:
        Path(args.json).write_text(json.dumps(report, indent=2))
    if tmp is not None and not args.keep:
        shutil.rmtree(tmp, ignore_errors=True)
    elif tmp is not None:
        print(f"kept {db}")
    return 0 if all(checks.values()) else 1


if __name__ == "__main__":
    sys.exit(main())
