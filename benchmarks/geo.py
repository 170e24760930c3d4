"""Geo-query benchmark (issue 4): "the latest samples of the devices near here".

    .venv/bin/python benchmarks/geo.py [--duration 10] [--connections 4] [--location every|once] [--json FILE]
    .venv/bin/python benchmarks/geo.py --backend postgresql      # or --db postgresql://... (already loaded)

1. Loads 10,000 ``Device`` entities spread uniformly over a disc of 25 km
   radius around Puerta del Sol, Madrid, with 100 samples each (one per
   minute) in-process through the store (``write_sync`` with big
   ``AppendSamples`` batches), then compacts it (DuckDB) or runs ``VACUUM
   (ANALYZE)`` (PostgreSQL: a private cluster started for the run, as in
   benchmarks/queries.py). Every sample has a ``temperature`` (Number).
   ``location`` (geo:json Point): ``--location every`` (default) puts it in
   every sample, as moving robots send it: each device wanders up to ~50 m
   around its spot, so there are 1,000,000 stored positions; ``--location
   once`` stores it only in the first sample (fixed sensors). ``--db``
   reuses a loaded DuckDB file (loading it there if missing) or database.
2. Starts the real server (``tsdb-service serve``, one process) on it and
   checks that the measured request answers correctly under sample
   semantics (a sample matches where its entity was when it was taken): for
   20 query points, ``/v2/entities`` lists exactly the entities with a
   sample within 1,000 m (computed here with pyproj ``Geod``), and lastN=10
   returns exactly the newest 10 temperatures taken within 1,000 m.
3. Drives it with ``benchmarks/loadgen.py`` (closed loop, keep-alive), a
   random query point in the inner 20 km per request (1,024 pre-built):
   ``GET /v2/types/Device/attrs/temperature?georel=near;maxDistance:1000
   &geometry=point&coords=<lat,lon>&lastN=10`` at 1 connection (latency of
   one query) and at ``--connections`` (throughput).
   For comparison it also measures the history of the same entities (those
   with a sample within 1,000 m, computed here) asked by ``id`` without geo,
   at 1 connection: the gap between the two is roughly the geo filter's cost.
4. Prints p50/p99 latency and requests/s, with PASS/FAIL against the target
   (geo p50 <= 30 ms at 1 and at ``--connections`` connections; no errors).
   Exit status 0 = all pass.
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
from datetime import UTC, datetime, timedelta
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import common
from common import HOST, bulk_load, finish_load, free_port, get, is_pg
from loadgen import build_request
from pgutil import BenchCluster
from pyproj import Geod

from queries import measure, start_server

ENTITIES = 10_000
SAMPLES = 100
STEP = timedelta(minutes=1)
START = datetime(2024, 5, 1, tzinfo=UTC)
ENTITY_TYPE = "Device"
CENTRE = (-3.7038, 40.4168)  # lon, lat: Puerta del Sol, Madrid
RADIUS_M = 25_000
QUERY_RADIUS_M = 20_000  # query points: inside the populated disc
MAX_DISTANCE = 1_000
LAST_N = 10
WANDER_M = 50
TARGET_P50_MS = 30.0
WGS84 = Geod(ellps="WGS84")


def entity_id(n: int) -> str:
    return f"urn:ngsi-ld:Device:{n:05d}"


def random_point(rng: random.Random, radius_m: float) -> tuple[float, float]:
    """(lon, lat) uniform over a disc of ``radius_m`` around CENTRE."""
    lon, lat, _ = WGS84.fwd(CENTRE[0], CENTRE[1], rng.uniform(0, 360), radius_m * math.sqrt(rng.random()))
    return round(lon, 6), round(lat, 6)


def positions(every: bool) -> list[list[tuple[float, float]]]:
    """Per entity, the position of each sample (a single one with ``every=False``).
    Deterministic: the same seed gives the same data, so checks can recompute it."""
    rng = random.Random(42)
    out = []
    for _ in range(ENTITIES):
        home = random_point(rng, RADIUS_M)
        if not every:
            out.append([home])
            continue
        path = []
        for _ in range(SAMPLES):
            lon, lat, _ = WGS84.fwd(home[0], home[1], rng.uniform(0, 360), WANDER_M * rng.random())
            path.append((round(lon, 6), round(lat, 6)))
        out.append(path)
    return out


def temperature(e: int, i: int) -> float:
    return round(15 + (e % 100) / 10 + i / 100, 3)


# --- 1. load ---------------------------------------------------------------------------


def load(db: Path | str, every: bool, batch_notifications: int = 50_000, cluster: BenchCluster | None = None) -> dict:
    import orjson

    from tsdb_service.core.model import AttrSample, EntitySample, Kind
    from tsdb_service.geo.encodings import from_geojson

    ids = [entity_id(e) for e in range(ENTITIES)]

    def steps():
        paths = positions(every)  # timed as part of the load, as it always was
        for i in range(SAMPLES):
            moment = START + i * STEP
            step = []
            for e in range(ENTITIES):
                attrs = [AttrSample("temperature", "Number", Kind.NUMBER, num=temperature(e, i))]
                if every or i == 0:
                    lon, lat = paths[e][i if every else 0]
                    value = {"type": "Point", "coordinates": [lon, lat]}
                    geo = from_geojson(value)
                    attrs.append(AttrSample("location", "geo:json", Kind.GEO, js=orjson.dumps(value).decode(), geo=geo))
                step.append(EntitySample("", "/", ids[e], ENTITY_TYPE, moment, attrs))
            yield step

    store, written, t_load = bulk_load(db, steps(), batch_notifications, progress_every=20)
    finished = finish_load(store, db, cluster)
    return {"samples": written, "load_s": round(t_load, 1), **finished}


# --- 2. correctness of what we measure ------------------------------------------------------


def query_path(lon: float, lat: float) -> str:
    return (
        f"/v2/types/{ENTITY_TYPE}/attrs/temperature?georel=near;maxDistance:{MAX_DISTANCE}"
        f"&geometry=point&coords={lat},{lon}&lastN={LAST_N}"
    )


def matching_samples(paths: list[list[tuple[float, float]]], lon: float, lat: float) -> dict[int, list[int]]:
    """Entity -> indexes of its samples taken within MAX_DISTANCE of (lon, lat):
    the semantics under test (a sample matches where its entity was then; with
    ``--location once`` the first position holds for every sample)."""
    firsts = [path[0] for path in paths]
    _, _, dist = WGS84.inv([lon] * ENTITIES, [lat] * ENTITIES, [p[0] for p in firsts], [p[1] for p in firsts])
    out = {}
    # Every position is within WANDER_M of home, so within 2 x WANDER_M of the first.
    for e in (e for e, d in enumerate(dist) if d <= MAX_DISTANCE + 2 * WANDER_M + 1):
        path = paths[e]
        _, _, d = WGS84.inv([lon] * len(path), [lat] * len(path), [p[0] for p in path], [p[1] for p in path])
        inside = [i for i, metres in enumerate(d) if metres <= MAX_DISTANCE]
        if len(path) == 1:
            inside = list(range(SAMPLES)) if inside else []
        if inside:
            out[e] = inside
    return out


def check_answers(port: int, every: bool, points: int = 20) -> dict:
    """For each point: /v2/entities lists exactly the entities with a sample
    within 1,000 m, and lastN=10 returns exactly the newest 10 such samples
    (ties in time by arrival: the load writes entities in id order)."""
    paths = positions(every)
    rng = random.Random(99)
    matched_counts = []
    for _ in range(points):
        lon, lat = random_point(rng, QUERY_RADIUS_M)
        inside = matching_samples(paths, lon, lat)
        expected = {entity_id(e) for e in inside}
        matched_counts.append(len(expected))
        status, body = get(
            port,
            f"/v2/entities?type={ENTITY_TYPE}&georel=near;maxDistance:{MAX_DISTANCE}"
            f"&geometry=point&coords={lat},{lon}&limit=10000",
        )
        got = {e["id"] for e in json.loads(body)} if status == 200 else None
        assert got == expected, (lat, lon, status, sorted(expected ^ (got or set()))[:10])
        status, body = get(port, query_path(lon, lat))
        assert status == 200, (status, body[:300])
        doc = json.loads(body)
        rows = set()
        for ent in [] if doc == [] else doc["entities"]:
            e = int(ent["id"].rsplit(":", 1)[1])
            for t, value in zip(ent["index"], ent["values"], strict=True):
                i = round((datetime.fromisoformat(t) - START) / STEP)
                assert value == temperature(e, i), (ent["id"], t, value)
                rows.add((i, e))
        newest = sorted((i, e) for e, indexes in inside.items() for i in indexes)[-LAST_N:]
        assert rows == set(newest), (lat, lon, sorted(rows ^ set(newest))[:10])
    return {
        "points_checked": points,
        "matched_min": min(matched_counts),
        "matched_max": max(matched_counts),
        "matched_mean": round(sum(matched_counts) / points, 1),
    }


# --- 3. load generation ---------------------------------------------------------------------


def requests(port: int, every: bool, n: int = 1024) -> tuple[list[bytes], list[bytes]]:
    """The geo request for ``n`` random points, and the history of the same
    entities (those with a sample within 1,000 m, computed here) asked by
    ``id`` without geo: the difference between the two is roughly what the
    geo filter costs."""
    paths = positions(every)
    rng = random.Random(7)
    geo_reqs, by_id = [], []
    for _ in range(n):
        lon, lat = random_point(rng, QUERY_RADIUS_M)
        geo_reqs.append(build_request("GET", query_path(lon, lat), HOST, port))
        ids = [entity_id(e) for e in sorted(matching_samples(paths, lon, lat))]
        if ids:
            by_id.append(
                build_request(
                    "GET", f"/v2/types/{ENTITY_TYPE}/attrs/temperature?id={','.join(ids)}&lastN={LAST_N}", HOST, port
                )
            )
    return geo_reqs, by_id


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
        "--db",
        help="reuse this DuckDB file (loaded there if missing) or this loaded postgresql:// "
        "database (default: load a fresh one)",
    )
    ap.add_argument(
        "--location",
        choices=("every", "once"),
        default="every",
        help="location in every sample (moving devices, default) or only the first",
    )
    ap.add_argument("--keep", action="store_true", help="keep the temporary database")
    ap.add_argument("--duration", type=float, default=10.0)
    ap.add_argument("--warmup", type=float, default=2.0)
    ap.add_argument("--connections", type=int, default=4, help="connections for the loaded run")
    ap.add_argument("--json", help="write the results here")
    args = ap.parse_args(argv)
    if args.db and is_pg(args.db):
        args.backend = "postgresql"
    every = args.location == "every"
    load_start = common.loadavg(None)
    where = "every sample" if every else "the first sample only"
    print(
        f"geo benchmark on {args.backend}: {ENTITIES:,} entities x {SAMPLES} samples, location in {where}", flush=True
    )

    tmp = Path(tempfile.mkdtemp(prefix="tsdb-geo-"))
    cluster: BenchCluster | None = None
    db: Path | str
    results: dict[str, dict] = {}
    try:
        if args.backend == "postgresql":
            if args.db:
                db, loaded = args.db, {"reused": "(a postgresql:// database)"}
            else:
                print("starting a private PostgreSQL cluster ...", flush=True)
                cluster = BenchCluster("geo").start()
                db = cluster.url
                print(f"loading into PostgreSQL {cluster.version} ({db}) ...", flush=True)
                loaded = load(db, every, cluster=cluster)
        elif args.db:
            db, loaded = Path(args.db), {"reused": args.db}
            if not db.exists():
                print(f"loading into {db} ...", flush=True)
                loaded = load(db, every)
        else:
            db = tmp / "geo.duckdb"
            print(f"loading into {db} ...", flush=True)
            loaded = load(db, every)
        print(f"  {loaded}", flush=True)

        port = free_port()
        server = start_server(db, port, tmp / "server.log")
        try:
            print("checking answers against pyproj ...", flush=True)
            checked = check_answers(port, every)
            print(f"  {checked}", flush=True)
            geo_reqs, by_id = requests(port, every)
            label = f"near;maxDistance:{MAX_DISTANCE} + lastN={LAST_N}"
            plan = [
                ("1conn", label, geo_reqs, 1),
                ("loaded", label, geo_reqs, args.connections),
                ("baseline", f"same entities by id=, no geo, lastN={LAST_N}", by_id, 1),
            ]
            for key, text, reqs, conns in plan:
                print(f"measuring {text} ({conns} connections, {args.duration:g} s) ...", flush=True)
                cpu0 = server.cpu_seconds()
                db_cpu0 = cluster.cpu_seconds() if cluster else math.nan
                stats = measure(port, reqs, conns, args.duration, args.warmup)
                cpu_ms = (server.cpu_seconds() - cpu0) / max(stats.total_ok, 1) * 1e3
                db_cpu_ms = ((cluster.cpu_seconds() - db_cpu0) / max(stats.total_ok, 1) * 1e3) if cluster else None
                results[key] = {
                    "label": text,
                    "connections": conns,
                    "server_cpu_ms_per_req": cpu_ms,
                    "db_cpu_ms_per_req": db_cpu_ms,
                    **stats.to_dict(),
                }
            rss = server.rss_bytes()
        finally:
            server.stop(60.0)
    finally:
        if cluster is not None:
            cluster.stop()

    checks = {
        f"p50 <= {TARGET_P50_MS:g} ms (1 connection)": _le(results["1conn"]["p50_ms"], TARGET_P50_MS),
        f"p50 <= {TARGET_P50_MS:g} ms ({args.connections} connections)": _le(
            results["loaded"]["p50_ms"], TARGET_P50_MS
        ),
        "no errors": all(r["errors"] == 0 and r["non_2xx"] == 0 for r in results.values()),
    }
    db_col = cluster is not None
    print()
    print(f"backend: {args.backend}, 1 server process")
    print(
        f"GET /v2/types/{ENTITY_TYPE}/attrs/temperature?georel=near;maxDistance:{MAX_DISTANCE}"
        f"&geometry=point&coords=<random>&lastN={LAST_N}"
    )
    print(
        f"{ENTITIES:,} entities x {SAMPLES} samples, location in {where}, "
        f"{checked['matched_mean']} entities within {MAX_DISTANCE} m on average"
    )
    common.print_scenarios(results, db_col, label_width=40, rps_digits=1)
    print(f"server RSS: {rss / 2**20:.0f} MiB")
    print(
        f"load average (1/5/15 min) at start {common.load_text(load_start, 2)}, at end {common.load_text(digits=2)} "
        f"on {os.cpu_count()} CPUs: other processes' load inflates every latency"
    )
    print()
    for name, ok in checks.items():
        print(f"{'PASS' if ok else 'FAIL'}  {name}")
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        common.write_json(
            args.json,
            {
                "benchmark": "geo",
                "backend": args.backend,
                "entities": ENTITIES,
                "samples_per_entity": SAMPLES,
                "load": loaded,
                "location": args.location,
                "check": checked,
                "results": results,
                "checks": checks,
                "rss_bytes": rss,
                "machine": {
                    "cpus": os.cpu_count(),
                    "load_average_start": load_start,
                    "load_average_end": common.loadavg(None),
                },
            },
        )
    if args.keep and isinstance(db, Path) and tmp in db.parents:
        print(f"kept {db}")
    else:
        shutil.rmtree(tmp, ignore_errors=True)
    return 0 if all(checks.values()) else 1


def _le(value, limit: float) -> bool:
    return value is not None and value <= limit


if __name__ == "__main__":
    sys.exit(main())
