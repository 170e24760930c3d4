"""History query benchmark: latency and throughput of the read API.

    .venv/bin/python benchmarks/queries.py [--duration 10] [--connections 8] [--json FILE]
    .venv/bin/python benchmarks/queries.py --backend postgresql [--scale 1] [--workers 1]

1. Loads 10,000,000 samples (1,000 entities x 10 attributes x 1,000
   samples, one notification every 90 s per entity) in-process through the
   store (``write_sync`` with big ``AppendSamples`` batches), compacts it
   (``compact(full=True)``) and closes it. ``--db FILE`` reuses a loaded file.
   ``--backend postgresql`` loads the same data set into a fresh database of
   a private PostgreSQL cluster started for the run (the store writes with
   ``COPY``), then runs ``VACUUM (ANALYZE)`` in place of the compaction.
   ``--scale S`` loads S x 1,000 samples per series instead (S >= 0.1); the
   scale is printed with every result and recorded in the JSON.
2. Starts the real server (``tsdb-service serve``) on that file or database.
3. Drives it with ``benchmarks/loadgen.py`` (closed loop, keep-alive,
   ``--connections`` connections, random entity per request):
   a. ``/v2/entities/{id}/attrs/{attr}?lastN=100``
   b. ``/v2/entities/{id}/attrs/{attr}?aggrMethod=avg&aggrPeriod=hour`` over one day
   c. ``/v2/types/{type}/attrs/{attr}?lastN=1000``
4. Prints p50/p99 latency, requests/s, server RSS and bytes on disk per
   stored sample, with PASS/FAIL against the targets (lastN p50 <= 5 ms and
   >= 2,000 req/s; hourly aggregation p50 <= 20 ms). Exit status 0 = all pass.
   On PostgreSQL it also prints the database server's CPU per request and its
   memory (PSS summed over its processes): it shares the two cores.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import random
import shutil
import sys
import tempfile
import time
from datetime import UTC, datetime, timedelta
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import common
from common import HOST, Server, bulk_load, finish_load, free_port, get, is_pg, open_store, ours_cmd
from loadgen import build_request, run_load
from pgutil import BenchCluster

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


def samples_per_series(scale: float) -> int:
    return round(SAMPLES * scale)


# --- 1. load ---------------------------------------------------------------------------


def load(
    db: Path | str, per_series: int = SAMPLES, batch_notifications: int = 20_000, cluster: BenchCluster | None = None
) -> dict:
    from tsdb_service.core.model import AttrSample, EntitySample, Kind

    names = [attr_name(a) for a in range(ATTRS)]
    ids = [entity_id(e) for e in range(ENTITIES)]
    rng = random.Random(42)

    def steps():
        for i in range(per_series):
            moment = START + i * STEP
            yield [
                EntitySample(
                    "",
                    "/",
                    ids[e],
                    ENTITY_TYPE,
                    moment,
                    [
                        AttrSample(names[a], "Number", Kind.NUMBER, num=e + i * 0.01 + a + rng.random())
                        for a in range(ATTRS)
                    ],
                )
                for e in range(ENTITIES)
            ]

    store, written, t_load = bulk_load(db, steps(), batch_notifications, progress_every=100)
    finished = finish_load(store, db, cluster)
    return {"samples": written, "load_s": round(t_load, 1), **finished, "samples_per_s": round(written / t_load)}


def engine_ceiling(db: Path | str, seconds: float = 4.0, threads: int = 2) -> dict:
    """The lastN=100 query alone, in-process, with no HTTP: what the database
    can do on this machine, for comparison with the served rate."""
    import threading

    from tsdb_service.core.query import Shape
    from tsdb_service.faces.quantumleap.params import history_query
    from tsdb_service.read.requests import RowsRead, SeriesSelect

    store = open_store(db)
    querier = store.querier()
    counts = []

    def worker(seed: int) -> None:
        rng = random.Random(seed)
        n = 0
        end = time.perf_counter() + seconds
        while time.perf_counter() < end:
            query = history_query(
                Shape.ENTITY_ATTR,
                {"lastN": "100"},
                {},
                "",
                10_000,
                entity_id=entity_id(rng.randrange(ENTITIES)),
                attr=attr_name(rng.randrange(ATTRS)),
            )
            refs = querier.series(SeriesSelect(query.scope, query.entities, {query.attrs[0].attr}))
            querier.raw_rows(
                RowsRead([r.sid for r in refs], query.time, newest_first=True, limit=100, offset=0, one_per_row=True)
            )
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


def start_server(db: Path | str, port: int, log_path: Path, workers: int = 1) -> Server:
    """``tsdb-service serve`` on the loaded database, healthy; ``TSDB_*`` of this shell are not passed."""
    return Server("server", ours_cmd(db, port, workers), port, log_path).start()


# --- 3. load generation ---------------------------------------------------------------------


def scenarios(port: int) -> dict[str, list[bytes]]:
    rng = random.Random(7)
    day_from = START.strftime("%Y-%m-%dT%H:%M:%SZ")
    day_to = (START + timedelta(days=1) - timedelta(seconds=1)).strftime("%Y-%m-%dT%H:%M:%SZ")
    out: dict[str, list[bytes]] = {"lastN": [], "hourly_avg": [], "type_lastN": []}
    for _ in range(4096):
        e, a = rng.randrange(ENTITIES), rng.randrange(ATTRS)
        out["lastN"].append(
            build_request("GET", f"/v2/entities/{entity_id(e)}/attrs/{attr_name(a)}?lastN=100", HOST, port)
        )
        out["hourly_avg"].append(
            build_request(
                "GET",
                f"/v2/entities/{entity_id(e)}/attrs/{attr_name(a)}?aggrMethod=avg&aggrPeriod=hour"
                f"&fromDate={day_from}&toDate={day_to}",
                HOST,
                port,
            )
        )
    for a in range(ATTRS):
        out["type_lastN"].append(
            build_request("GET", f"/v2/types/{ENTITY_TYPE}/attrs/{attr_name(a)}?lastN=1000", HOST, port)
        )
    return out


def hours_covered(per_series: int) -> int:
    """Hourly buckets the aggregation over the first day finds (24 at full scale)."""
    return min(24, math.ceil(per_series * STEP.total_seconds() / 3600))


def check_answers(port: int, per_series: int = SAMPLES) -> None:
    """The requests we measure must answer what we loaded."""
    e, a = 17, 3
    status, body = get(port, f"/v2/entities/{entity_id(e)}/attrs/{attr_name(a)}?lastN=100")
    doc = json.loads(body)
    assert status == 200 and len(doc["values"]) == 100, (status, body[:300])
    last = (START + (per_series - 1) * STEP).strftime("%Y-%m-%dT%H:%M:%S.000+00:00")
    assert doc["index"][-1] == last, doc["index"][-1]
    status, body = get(
        port,
        f"/v2/entities/{entity_id(e)}/attrs/{attr_name(a)}?aggrMethod=avg&aggrPeriod=hour"
        f"&fromDate=2024-05-01T00:00:00Z&toDate=2024-05-01T23:59:59Z",
    )
    doc = json.loads(body)
    assert status == 200 and len(doc["values"]) == hours_covered(per_series), (status, body[:300])
    status, body = get(port, f"/v2/types/{ENTITY_TYPE}/attrs/{attr_name(a)}?lastN=1000")
    doc = json.loads(body)
    assert status == 200 and sum(len(x["values"]) for x in doc["entities"]) == 1000, (status, body[:300])


def measure(port: int, requests: list[bytes], connections: int, duration: float, warmup: float):
    n = len(requests)
    return run_load(
        HOST, port, lambda seq: requests[seq % n], connections=connections, duration=duration, warmup=warmup
    )


# --- 4. report -------------------------------------------------------------------------------


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument(
        "--backend",
        choices=("duckdb", "postgresql"),
        default="duckdb",
        help="duckdb (default: a temp file) or postgresql (a private cluster started for the run)",
    )
    ap.add_argument(
        "--db", help="reuse this loaded DuckDB file, or this loaded postgresql:// database (default: load a fresh one)"
    )
    ap.add_argument(
        "--scale",
        type=float,
        default=1.0,
        help="fraction of the 1,000 samples per series to load (default 1 = 10M samples; min 0.1)",
    )
    ap.add_argument("--workers", type=int, default=1, help="server workers (PostgreSQL only; default 1)")
    ap.add_argument("--keep", action="store_true", help="keep the temporary database")
    ap.add_argument("--duration", type=float, default=10.0)
    ap.add_argument(
        "--warmup",
        type=float,
        default=6.0,
        help="seconds of load before measuring (default 6: long enough to read each of the "
        "~3,400 series the scenarios use once, as a running deployment's dashboards have; "
        "--warmup 0.5 shows first reads)",
    )
    ap.add_argument("--connections", type=int, default=8)
    ap.add_argument("--type-connections", type=int, default=2, help="connections for the /v2/types scenario")
    ap.add_argument("--json", help="write the results here")
    args = ap.parse_args(argv)
    if args.db and is_pg(args.db):
        args.backend = "postgresql"
    if not 0.1 <= args.scale <= 1.0:
        ap.error("--scale must be between 0.1 (100 samples per series: lastN=100 needs them) and 1")
    if args.workers < 1 or (args.workers > 1 and args.backend != "postgresql"):
        ap.error("--workers > 1 needs PostgreSQL (a DuckDB file belongs to one process)")

    per_series = samples_per_series(args.scale)
    samples = ENTITIES * ATTRS * per_series
    dataset = (
        f"{ENTITIES:,} entities x {ATTRS} attrs x {per_series:,} samples = {samples:,} samples "
        f"(scale {args.scale:g}"
        + (")" if per_series == SAMPLES else " -- NOT the 10,000,000-sample data set of the target)")
    )
    print(f"history query benchmark on {args.backend}: {dataset}", flush=True)

    tmp = Path(tempfile.mkdtemp(prefix="tsdb-queries-"))
    cluster: BenchCluster | None = None
    db: Path | str
    try:
        if args.backend == "postgresql":
            if args.db:
                db = args.db
                loaded = {"samples": samples, "reused": "(a postgresql:// database)"}
            else:
                print("starting a private PostgreSQL cluster ...", flush=True)
                cluster = BenchCluster("queries").start()
                db = cluster.url
                print(f"loading {samples:,} samples into PostgreSQL {cluster.version} ({db}) ...", flush=True)
                loaded = load(db, per_series, cluster=cluster)
        elif args.db:
            db = Path(args.db)
            loaded = {"samples": samples, "reused": str(db)}
            if not db.exists():
                print(f"loading {samples:,} samples into {db} ...", flush=True)
                loaded = load(db, per_series)
        else:
            db = tmp / "bench.duckdb"
            print(f"loading {samples:,} samples into {db} ...", flush=True)
            loaded = load(db, per_series)
        print(f"  {loaded}", flush=True)
        if cluster is not None:
            disk = cluster.database_bytes()
        elif isinstance(db, Path):
            wal = Path(str(db) + ".wal")
            disk = db.stat().st_size + (wal.stat().st_size if wal.exists() else 0)
        else:
            disk = None

        print("measuring the engine alone (same lastN query in-process, no HTTP) ...", flush=True)
        ceiling = engine_ceiling(db)
        print(f"  {ceiling}", flush=True)

        port = free_port()
        log_path = (tmp if isinstance(db, str) or tmp in db.parents else db.parent) / "server.log"
        server = start_server(db, port, log_path, args.workers)
        results: dict[str, dict] = {}
        try:
            check_answers(port, per_series)
            reqs = scenarios(port)
            plan = [
                ("lastN", "lastN", "lastN=100, one entity attribute", args.connections),
                ("hourly_avg", "hourly_avg", "avg per hour over one day, one entity attribute", args.connections),
                ("type_lastN", "type_lastN", "/v2/types/{type}/attrs/{attr}?lastN=1000", args.type_connections),
                ("lastN_1conn", "lastN", "lastN=100, unloaded (1 connection)", 1),
                ("hourly_avg_1conn", "hourly_avg", "avg per hour, unloaded (1 connection)", 1),
            ]
            rss_peak = server.rss_bytes()
            db_mem_peak = cluster.memory_bytes() if cluster else None
            for key, scenario, label, conns in plan:
                duration = args.duration if key != "type_lastN" else max(min(5.0, args.duration), args.duration / 2)
                print(f"measuring {label} ({conns} connections, {duration:g} s) ...", flush=True)
                cpu0 = server.cpu_seconds()
                db_cpu0 = cluster.cpu_seconds() if cluster else math.nan
                stats = measure(port, reqs[scenario], conns, duration, args.warmup)
                cpu1 = server.cpu_seconds()
                db_cpu1 = cluster.cpu_seconds() if cluster else math.nan
                rss_peak = max(rss_peak, server.rss_bytes())
                if cluster is not None:
                    db_mem_peak = max(db_mem_peak or 0, cluster.memory_bytes() or 0)
                cpu_ms = (cpu1 - cpu0) / max(stats.total_ok, 1) * 1e3
                db_cpu_ms = (db_cpu1 - db_cpu0) / max(stats.total_ok, 1) * 1e3
                results[key] = {
                    "label": label,
                    "connections": conns,
                    "server_cpu_ms_per_req": cpu_ms,
                    **({"db_cpu_ms_per_req": db_cpu_ms} if cluster else {}),
                    **stats.to_dict(),
                }
            rss_end = server.rss_bytes()
            db_mem_end = cluster.memory_bytes() if cluster else None
        finally:
            server.stop(60.0)
    finally:
        if cluster is not None:
            cluster.stop()

    a, b = results["lastN"], results["hourly_avg"]
    checks = {
        "lastN p50 <= 5 ms": a["p50_ms"] is not None and a["p50_ms"] <= 5.0,
        "lastN >= 2000 req/s": a["rps"] >= 2000,
        "hourly avg p50 <= 20 ms": b["p50_ms"] is not None and b["p50_ms"] <= 20.0,
        "no errors": all(r["errors"] == 0 and r["non_2xx"] == 0 for r in results.values()),
    }
    print()
    print(f"backend: {args.backend}" + (f", {args.workers} workers" if args.workers > 1 else ", 1 server process"))
    print(f"data set: {dataset}")
    db_col = cluster is not None
    common.print_scenarios(results, db_col, label_width=48, rps_digits=0)
    print(
        f"{'engine alone: lastN=100 in-process, 2 threads':<48} {'-':>5} {ceiling['queries_per_s']:>8.0f} "
        f"{'-':>8} {'-':>8} {ceiling['cpu_ms_per_query']:>10.2f}"
    )
    if db_col:
        print("(cpu ms/req: the service process(es); db ms/req: the PostgreSQL server, same cores)")
    print()
    print(f"server RSS: {rss_end / 2**20:.0f} MiB (peak seen {rss_peak / 2**20:.0f} MiB)")
    if db_mem_end is not None:
        print(
            f"PostgreSQL server memory (PSS, all its processes): {db_mem_end / 2**20:.0f} MiB "
            f"(peak seen {db_mem_peak / 2**20:.0f} MiB; shared_buffers = 256 MB)"
        )
    if disk is not None:
        print(
            f"on disk: {disk / 2**20:.0f} MiB for {samples:,} samples = {disk / samples:.1f} bytes/sample"
            + (" (pg_database_size: heap + index + catalog)" if db_col else "")
        )
    print()
    for name, ok in checks.items():
        print(f"{'PASS' if ok else 'FAIL'}  {name}")
    report = {
        "benchmark": "queries",
        "backend": args.backend,
        "workers": args.workers,
        "scale": args.scale,
        "entities": ENTITIES,
        "attrs": ATTRS,
        "samples_per_series": per_series,
        "samples": samples,
        "dataset": dataset,
        "load": loaded,
        "results": results,
        "rss_bytes": rss_end,
        "rss_peak_bytes": rss_peak,
        "db_server_memory_bytes": db_mem_end,
        "db_server_memory_peak_bytes": db_mem_peak,
        "disk_bytes": disk,
        "bytes_per_sample": disk / samples if disk is not None else None,
        "checks": checks,
        "engine_alone": ceiling,
        "machine": {"cpus": os.cpu_count()},
    }
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        common.write_json(args.json, report)
    if not args.keep or isinstance(db, str) or tmp not in db.parents:
        shutil.rmtree(tmp, ignore_errors=True)
    else:
        print(f"kept {db}")
    return 0 if all(checks.values()) else 1


if __name__ == "__main__":
    sys.exit(main())
