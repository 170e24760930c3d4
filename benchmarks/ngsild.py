"""NGSI-LD temporal API benchmark (issue 13).

    .venv/bin/python benchmarks/ngsild.py [--scale 1.0] [--backend duckdb|postgresql] [--requests 200] [--json FILE]

1. Loads ``100,000 x scale`` ``Sensor`` entities with 100 instances each
   (one every 15 minutes from 2024-05-01T00:00Z, so a day holds 96) through
   the store's write path (``write_sync`` with big ``AppendSamples``
   batches): every instance has a ``temperature`` Property with its own
   ``observedAt``; every 10th also a ``location`` GeoProperty (a Point
   within 25 km of Madrid). Then compacts (DuckDB) or runs ``VACUUM
   (ANALYZE)`` (PostgreSQL, a private cluster as in benchmarks/queries.py).
2. Serves the app as deployed, ``tsdb-service serve`` in its own process on a
   free port, and measures from this process, over real HTTP, one connection,
   ``--requests`` each. (Until 2026-11-25 the server ran in this process and
   shared its interpreter with the client's JSON parsing; benchmarks/README.md
   has both harnesses side by side.)

   * retrieve: ``GET /ngsi-ld/v1/temporal/entities/{id}`` for one day
     (``timerel=between``), a random entity per request; target p50 <= 20 ms;
   * aggregate: ``format=aggregatedValues&aggrMethods=avg,max&
     aggrPeriodDuration=PT1H`` over 100 entities (10,000 instances);
     target p50 <= 20 ms;
   * q + geo (the server's read budget raised to 3 series per entity, as
     a type query reads every entity's two series):
     ``type=Sensor&q=temperature>24&georel=near;maxDistance==3000``
     over a two-hour window that holds one location instance of every
     entity, ``lastN=1``; target p50 <= 100 ms. About 1.4 % of the
     entities are within 3 km and a quarter of those pass ``q``, so every
     scale down to 0.01 matches some (the mean is reported; none is an error).

3. Prints p50/p99 per request kind, the server process's RSS and the load average
   (the machine may be shared), PASS/FAIL against the targets (exit 0 = all
   pass). Not a test: run it by hand.
"""

from __future__ import annotations

import argparse
import json
import math
import random
import statistics
import sys
import tempfile
import time
from datetime import UTC, datetime, timedelta
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import common
from common import free_port

START = datetime(2024, 5, 1, tzinfo=UTC)
STEP = timedelta(minutes=15)
INSTANCES = 100
CENTRE = (-3.7038, 40.4168)
TARGETS = {"retrieve": 20.0, "aggregate": 20.0, "q+geo": 100.0}


def entity_id(n: int) -> str:
    return f"urn:ngsi-ld:Sensor:{n:06d}"


def place(rng: random.Random) -> tuple[float, float]:
    distance, bearing = 25_000 * math.sqrt(rng.random()), rng.random() * 2 * math.pi
    return (
        CENTRE[0] + distance * math.sin(bearing) / (111_320 * math.cos(math.radians(CENTRE[1]))),
        CENTRE[1] + distance * math.cos(bearing) / 110_540,
    )


def load(settings, entities: int) -> dict:
    import orjson

    from tsdb_service.core.model import AttrSample, EntitySample, Kind
    from tsdb_service.geo.encodings import from_geojson
    from tsdb_service.storage import open_store
    from tsdb_service.write.ops import AppendSamples

    rng = random.Random(13)
    spots = [place(rng) for _ in range(entities)]
    store = open_store(settings)
    t0 = time.perf_counter()
    batch: list = []
    written = 0
    try:
        for i in range(INSTANCES):
            moment = START + i * STEP
            for e in range(entities):
                temp = AttrSample(
                    "temperature",
                    "Property",
                    Kind.NUMBER,
                    num=15 + 10 * math.sin(e + i / 10),
                    md='{"unitCode":"CEL"}',
                    observed_at=moment,
                )
                attrs = [temp]
                if i % 10 == 0:
                    value = {"type": "Point", "coordinates": list(spots[e])}
                    attrs.append(
                        AttrSample(
                            "location",
                            "GeoProperty",
                            Kind.GEO,
                            js=orjson.dumps(value).decode(),
                            geo=from_geojson(value),
                            observed_at=moment,
                        )
                    )
                batch.append(EntitySample("bench", "/", entity_id(e), "Sensor", moment, attrs))
                written += len(attrs)
                if len(batch) >= 50_000:
                    store.write_sync([AppendSamples(batch, dedup=False)])
                    batch = []
        if batch:
            store.write_sync([AppendSamples(batch, dedup=False)])
        load_s = time.perf_counter() - t0
        if hasattr(store, "compact"):
            store.compact(full=True)
    finally:
        store.close()
    if settings.backend == "postgresql":
        import psycopg

        with psycopg.connect(settings.db, autocommit=True) as conn:
            conn.execute("VACUUM (ANALYZE)")
    return {"instances": written, "load_s": round(load_s, 1), "total_s": round(time.perf_counter() - t0, 1)}


def serve(db: str, port: int, read_max_series: int, workdir: Path) -> common.Server:
    """``tsdb-service serve`` on ``db`` as its own process (uvloop, httptools),
    the type query's read budget raised through the environment."""
    env = {"TSDB_READ_MAX_SERIES": str(read_max_series)}
    return common.spawned("ngsild-server", common.ours_cmd(db, port), port, workdir, env).start()


def requests(kind: str, entities: int, rng: random.Random) -> tuple[str, dict]:
    base = "/ngsi-ld/v1/temporal/entities"
    if kind == "retrieve":
        day = START + timedelta(hours=1)
        return f"{base}/{entity_id(rng.randrange(entities))}", {
            "timerel": "between",
            "timeAt": day.isoformat(),
            "endTimeAt": (day + timedelta(days=1)).isoformat(),
        }
    if kind == "aggregate":
        first = rng.randrange(max(1, entities - 100))
        return base, {
            "id": ",".join(entity_id(first + k) for k in range(min(100, entities))),
            "limit": "100",
            "attrs": "temperature",
            "format": "aggregatedValues",
            "aggrMethods": "avg,max",
            "aggrPeriodDuration": "PT1H",
        }
    lon, lat = place(rng)
    start = START + 10 * rng.randrange(INSTANCES // 10) * STEP  # a location instance (every 10th) is in the window
    return base, {
        "type": "Sensor",
        "attrs": "temperature",
        "q": "temperature>24",
        "lastN": "1",
        "limit": "1000",
        "georel": "near;maxDistance==3000",
        "geometry": "Point",
        "coordinates": json.dumps([lon, lat]),
        "timerel": "between",
        "timeAt": start.isoformat(),
        "endTimeAt": (start + 8 * STEP).isoformat(),
    }


def measure(port: int, kind: str, entities: int, n: int) -> dict:
    import httpx

    rng = random.Random(kind)
    times = []
    sizes = []
    with httpx.Client(base_url=f"http://127.0.0.1:{port}", headers={"NGSILD-Tenant": "bench"}, timeout=60) as http:
        for i in range(n + 5):
            path, params = requests(kind, entities, rng)
            t0 = time.perf_counter()
            response = http.get(path, params=params)
            elapsed = (time.perf_counter() - t0) * 1000
            if response.status_code not in (200, 206):
                raise SystemExit(f"{kind}: {response.status_code} {response.text[:300]}")
            if i >= 5:  # warm-up
                times.append(elapsed)
                body = response.json()
                sizes.append(len(body.get("temperature", [])) if kind == "retrieve" else len(body))
    times.sort()
    summary = {
        "p50_ms": round(statistics.median(times), 1),
        "p99_ms": round(times[int(len(times) * 0.99) - 1], 1),
        ("instances" if kind == "retrieve" else "entities"): round(statistics.mean(sizes), 1),
    }
    if not any(sizes):
        raise SystemExit(f"{kind}: no request matched anything, so it measured nothing: {summary}")
    return summary


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scale", type=float, default=1.0, help="entities = 100,000 x scale")
    parser.add_argument("--backend", choices=("duckdb", "postgresql"), default="duckdb")
    parser.add_argument("--db", help="a DuckDB file or postgresql:// URL to load into (default: a temporary one)")
    parser.add_argument("--requests", type=int, default=200)
    parser.add_argument(
        "--skip-load",
        action="store_true",
        help="measure --db as it is (loaded by an earlier run with the same --scale)",
    )
    parser.add_argument("--json", help="write the results here")
    args = parser.parse_args(argv)

    from tsdb_service.core.config import Settings

    entities = max(100, int(100_000 * args.scale))
    cluster = None
    db = args.db
    if db is None and args.backend == "postgresql":
        import pgutil  # noqa: F401 - puts the repository root on the path

        from tests.support.pg_cluster import PgCluster

        cluster = PgCluster().start()
        db = cluster.database("ngsild_bench")
    elif db is None:
        db = str(Path(tempfile.mkdtemp(prefix="ngsild-bench-")) / "bench.duckdb")
    # A type query over all entities reads 2 series per entity: past the
    # default read budget (TSDB_READ_MAX_SERIES=50,000) from scale 0.25 on.
    read_max_series = max(50_000, 3 * entities)
    settings = Settings(db=db, read_max_series=read_max_series)
    server = None
    try:
        loaded = {}
        if not args.skip_load:
            print(f"loading {entities:,} entities x {INSTANCES} instances into {args.backend} ...", flush=True)
            loaded = load(settings, entities)
            print(f"  {loaded}", flush=True)
        port = free_port()
        workdir = Path(tempfile.mkdtemp(prefix="ngsild-server-"))
        speed = common.speed_probe(workdir)
        print(f"  machine: {common.speed_text(speed)}, load average {common.load_text()}", flush=True)
        server = serve(db, port, read_max_series, workdir)
        results = {"entities": entities, "backend": args.backend, **loaded, "speed": speed}
        ok = True
        for kind in TARGETS:
            got = measure(port, kind, entities, args.requests)
            verdict = got["p50_ms"] <= TARGETS[kind]
            ok &= verdict
            results[kind] = got
            print(
                f"  {kind:10s} p50 {got['p50_ms']:7.1f} ms  p99 {got['p99_ms']:7.1f} ms  "
                f"target p50 <= {TARGETS[kind]:.0f} ms  {'PASS' if verdict else 'FAIL'}  {got}",
                flush=True,
            )
        rss = server.rss_bytes()
        results["rss_mb"] = round(rss / 2**20, 1) if rss is not None else None
        results["load_average"] = common.loadavg(1)
        print(f"  RSS {results['rss_mb']} MB, load average {results['load_average']}", flush=True)
    finally:
        if server is not None:
            server.stop()
        if cluster is not None:
            cluster.stop()
    if args.json:
        common.write_json(args.json, results)
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
