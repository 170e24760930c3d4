"""The growth curve (issue 15): the same measurements at 1M, 10M, 100M stored samples.

    .venv/bin/python benchmarks/compare.py --only growth --sizes 1M,10M,100M [--growth-backends duckdb,postgresql]
    .venv/bin/python benchmarks/growth.py --sizes 1M,10M --backends duckdb      # the same, directly

For each backend and size, on a fresh database:

1. creates the schema by opening the store (migrations), then bulk-loads
   ``size`` samples in the database itself, bypassing HTTP: 200 Lawnmower
   entities x 5 numeric attributes = 1,000 series (the catalog stays the same
   at every size, so what grows is only the depth of each series), one sample
   per series per minute from 2024-05-01, the samples of one entity at one
   minute sharing a row id as the service writes them. DuckDB: ``INSERT ...
   SELECT`` from ``range()`` into the sorted table, in (sid, t) order, as the
   compactor leaves it; PostgreSQL: ``INSERT ... SELECT`` from
   ``generate_series`` into ``samples`` (B-tree kept), the id sequences
   advanced past the loaded ids, then ``VACUUM (ANALYZE)``;
2. checks the layout: one notification for the same entity, parsed by the
   service's own parser and written through the store's own write path, must
   produce rows equal to the bulk-loaded ones in every column but rid, iid, t and
   num (else the run stops: the figures would not be the service's);
3. starts the server and measures: start-up time (spawn to /health 200),
   RSS after start, lastN=100 on one series (1 connection), the hourly
   average over the last 12 hours of one series (1 connection), ingest at 16
   connections (the Lawnmower notifications of compare.py), RSS at the end,
   and bytes on disk per sample.

It prints the curve and two verdicts: one-series latencies flat within 2x
from the smallest to the largest size, and RSS not growing with stored data
(largest <= 1.25 x smallest + 64 MiB: the catalog is constant). Sizes it is
not asked to run are estimated from the measured load rate and bytes per
sample, so the cost of 100M is known before running it.
"""

from __future__ import annotations

import argparse
import random
import shutil
import sys
import tempfile
import time
from datetime import UTC, datetime, timedelta
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import common
import lawnmower
import loads
import wrkrun

TENANT = "benchgrowth"
ENTITIES = 200
ATTRS = ("batteryLevel", "speed", "bladeSpeed", "cutHeight", "motorTemperature")
SERIES = ENTITIES * len(ATTRS)
START = datetime(2024, 5, 1, tzinfo=UTC)
# DuckDB: one INSERT per this many samples (memory of the ORDER BY stays bounded).
CHUNK = 20_000_000


def parse_size(text: str) -> int:
    text = text.strip().upper()
    mult = {"K": 10**3, "M": 10**6, "G": 10**9}.get(text[-1:], 1)
    return int(float(text.rstrip("KMG")) * mult)


def entity_id(e: int) -> str:
    return f"urn:ngsi-ld:Lawnmower:g{e:03d}"


def per_series(size: int) -> int:
    return max(100, size // SERIES)


# --- bulk load ---------------------------------------------------------------------------


def _series_rows() -> list[list]:
    rows = [[], [], [], [], [], []]
    for e in range(ENTITIES):
        for a, name in enumerate(ATTRS):
            for col, v in zip(
                rows, (e * len(ATTRS) + a + 1, TENANT, "/", entity_id(e), lawnmower.ENTITY_TYPE, name), strict=False
            ):
                col.append(v)
    return rows


def load_duckdb(path: str, size: int) -> dict:
    import duckdb

    from tsdb_service.storage.duckdb.store import DuckDBStore

    DuckDBStore(path).close()  # schema
    k = per_series(size)
    con = duckdb.connect(path)
    t0 = time.perf_counter()
    try:
        sid, tenant, sp, eid, etype, attr = _series_rows()
        con.execute(
            "INSERT INTO series BY NAME SELECT unnest($1::INTEGER[]) AS sid, unnest($2::VARCHAR[]) AS tenant, "
            "unnest($3::VARCHAR[]) AS service_path, unnest($4::VARCHAR[]) AS entity_id, "
            "unnest($5::VARCHAR[]) AS entity_type, unnest($6::VARCHAR[]) AS attr",
            [sid, tenant, sp, eid, etype, attr],
        )
        step = max(1, CHUNK // (len(ATTRS) * k))
        for e0 in range(0, ENTITIES, step):
            con.execute(
                f"""INSERT INTO samples BY NAME
                SELECT (kk * {ENTITIES} + e + 1)::BIGINT AS rid, (e * {len(ATTRS)} + a + 1)::INTEGER AS sid,
                       ((kk * {ENTITIES} + e) * {len(ATTRS)} + a + 1)::BIGINT AS iid,
                       TIMESTAMP '2024-05-01' + to_minutes(kk) AS t, 1::UTINYINT AS kind, 'Number' AS atype,
                       (e + a + (kk % 1440) / 100.0)::DOUBLE AS num
                FROM range(?, ?) r1(e), range({len(ATTRS)}) r2(a), range(?) r3(kk)
                ORDER BY sid, t""",
                [e0, min(ENTITIES, e0 + step), k],
            )
        con.execute("CHECKPOINT")
    finally:
        con.close()
    return {"samples": SERIES * k, "load_s": round(time.perf_counter() - t0, 1)}


def load_postgres(url: str, size: int) -> dict:
    import psycopg

    from tsdb_service.storage.postgres.store import PostgresStore

    PostgresStore(url).close()  # schema
    k = per_series(size)
    t0 = time.perf_counter()
    with psycopg.connect(url, autocommit=True) as conn:
        sid, tenant, sp, eid, etype, attr = _series_rows()
        conn.execute(
            "INSERT INTO series (sid, tenant, service_path, entity_id, entity_type, attr) "
            "SELECT * FROM unnest(%s::int[], %s::text[], %s::text[], %s::text[], %s::text[], %s::text[])",
            [sid, tenant, sp, eid, etype, attr],
        )
        conn.execute("SELECT setval(pg_get_serial_sequence('series', 'sid'), %s)", [SERIES])
        step = max(1, 5_000_000 // (len(ATTRS) * k))
        for e0 in range(0, ENTITIES, step):
            conn.execute(
                f"""INSERT INTO samples (rid, sid, t, kind, atype, num)
                SELECT kk::bigint * {ENTITIES} + e + 1, e * {len(ATTRS)} + a + 1,
                       TIMESTAMP '2024-05-01' + make_interval(mins => kk), 1, 'Number',
                       e + a + (kk %% 1440) / 100.0
                FROM generate_series(%s::int, %s::int) e, generate_series(0, {len(ATTRS) - 1}) a,
                     generate_series(0, %s::int) kk
                ORDER BY 2, 3""",
                [e0, min(ENTITIES, e0 + step) - 1, k - 1],
            )
        conn.execute("SELECT setval('sample_rid_seq', %s)", [k * ENTITIES])
        # As the writers keep it (migration 0009): these samples have no observedAt.
        conn.execute("INSERT INTO untimed_series (sid) SELECT sid FROM series ON CONFLICT DO NOTHING")
        conn.execute("VACUUM (ANALYZE) samples")
        conn.execute("CHECKPOINT")
    return {"samples": SERIES * k, "load_s": round(time.perf_counter() - t0, 1)}


# --- the layout check ---------------------------------------------------------------------


def check_layout(db: str, size: int) -> dict:
    """Write one notification for entity 0 through the service's parser and
    store, then compare its rows with the bulk-loaded ones."""
    from tsdb_service.parse import parse_notification
    from tsdb_service.write.ops import AppendSamples

    moment = START + timedelta(minutes=per_series(size) + 5)
    attrs = ",".join(f'"{a}":{{"type":"Number","value":{i + 0.5},"metadata":{{}}}}' for i, a in enumerate(ATTRS))
    body = (
        f'{{"subscriptionId":"{lawnmower.SUBSCRIPTION}","data":[{{"id":"{entity_id(0)}","type":"Lawnmower",'
        f'"TimeInstant":{{"type":"DateTime","value":"{moment:%Y-%m-%dT%H:%M:%S}.000Z","metadata":{{}}}},'
        f"{attrs}}}]}}"
    ).encode()
    hdrs = {k.lower(): v for k, v in lawnmower.headers(TENANT).items()}
    entities = parse_notification(body, hdrs, received_at=datetime.now(UTC), values_layout=lambda *a: None)
    pg = db.startswith("postgresql://")
    store = compare_store(db)
    try:
        store.write_sync([AppendSamples(entities)])
    finally:
        store.close()
    sql = (
        "SELECT * FROM samples_all WHERE sid BETWEEN 1 AND {n} AND t IN (TIMESTAMP '2024-05-01', {p}) ORDER BY t, sid"
    ).format(n=len(ATTRS), p="%s" if pg else "?")
    stamp = moment.replace(tzinfo=None)
    if pg:
        import psycopg

        with psycopg.connect(db) as conn:
            cur = conn.execute(sql, [stamp])
            names = [d.name for d in cur.description]
            rows = cur.fetchall()
    else:
        import duckdb

        con = duckdb.connect(db, read_only=True)
        try:
            cur = con.execute(sql, [stamp])
            names = [d[0] for d in cur.description]
            rows = cur.fetchall()
        finally:
            con.close()
    if len(rows) != 2 * len(ATTRS):
        raise RuntimeError(f"layout check: expected {2 * len(ATTRS)} rows, found {len(rows)}")
    keep = [i for i, n in enumerate(names) if n not in ("rid", "iid", "t", "num")]  # ids: counters, unique
    bulk, service = rows[: len(ATTRS)], rows[len(ATTRS) :]
    for b, s in zip(bulk, service, strict=False):
        if [b[i] for i in keep] != [s[i] for i in keep]:
            raise RuntimeError(f"layout check: bulk row {b} differs from the service's {s} (columns {names})")
    if len({s[names.index("rid")] for s in service}) != 1:
        raise RuntimeError("layout check: the service gave one entity's samples several row ids")
    return {"columns": names, "ok": True}


def compare_store(db: str):
    if db.startswith("postgresql://"):
        from tsdb_service.storage.postgres.store import PostgresStore

        return PostgresStore(db)
    from tsdb_service.storage.duckdb.store import DuckDBStore

    return DuckDBStore(db)


# --- measuring ---------------------------------------------------------------------------


def measure(db: str, size: int, runner: loads.Runner, workdir: Path, tag: str) -> dict:
    port = common.free_port()
    server = common.spawned(f"growth-{tag}", common.ours_cmd(db, port, 1), port, workdir)
    server.start(timeout=600)
    out = {"startup_s": round(server.startup_s, 2), "rss_start_mib": round((server.rss_bytes() or 0) / 2**20)}
    try:
        rng = random.Random(5)
        hdrs = lawnmower.query_headers(TENANT)
        # The last 12 hours, ending after the newest sample: inside the data
        # at every size (1M is 1,000 minutes per series) and starting
        # mid-hour at every size, so every size answers the same question
        # (on DuckDB: hourly partials plus one statement for the cut hour).
        end = START + timedelta(minutes=per_series(size) + 1)
        day = f"fromDate={end - timedelta(hours=12):%Y-%m-%dT%H:%M:%S}Z&toDate={end:%Y-%m-%dT%H:%M:%S}Z"
        picks = [(rng.randrange(ENTITIES), rng.choice(ATTRS)) for _ in range(64)]
        lastn = [f"/v2/entities/{entity_id(e)}/attrs/{a}?lastN=100" for e, a in picks]
        hourly = [f"/v2/entities/{entity_id(e)}/attrs/{a}?aggrMethod=avg&aggrPeriod=hour&{day}" for e, a in picks]
        for key, paths in (("lastN1", lastn), ("hourly1", hourly)):
            runs = runner.repeat(server.url, loads.get_load(server.url, paths, hdrs), 1)
            out[key] = loads.summary(runs, "p50_ms")
            out[key + "_errors"] = sum(r["non_2xx"] + r["errors"] for r in runs)
        runs = runner.repeat(server.url, loads.ingest_load(server.url, f"g{tag}", []), 16)
        out["ingest16"] = loads.summary(runs, "rps")
        out["ingest16_p99"] = loads.summary(runs, "p99_ms")
        out["rss_end_mib"] = round((server.rss_bytes() or 0) / 2**20)
    finally:
        server.stop()
    return out


def db_bytes(db: str, cluster) -> int:
    if cluster is not None:
        return cluster.database_bytes()
    return sum(p.stat().st_size for p in Path(db).parent.glob(Path(db).name + "*"))


def run(sizes_text: str, backends_text: str, runner: loads.Runner, workdir: Path) -> dict:
    sizes = [parse_size(s) for s in sizes_text.split(",") if s.strip()]
    backends = [b.strip() for b in backends_text.split(",") if b.strip()]
    curve: dict = {}
    for backend in backends:
        points = curve[backend] = []
        for size in sizes:
            tag = f"{backend}-{size}"
            print(f"- growth {backend}, {size:,} samples: bulk load ...", flush=True)
            cluster = None
            try:
                if backend == "postgresql":
                    from pgutil import BenchCluster

                    cluster = BenchCluster(f"growth{size}").start()
                    db = cluster.url
                    loaded = load_postgres(db, size)
                else:
                    db = str(workdir / f"growth-{size}.duckdb")
                    loaded = load_duckdb(db, size)
                print(f"    {loaded}", flush=True)
                check_layout(db, size)
                point = {
                    "size": size,
                    **loaded,
                    "bytes_per_sample": round(db_bytes(db, cluster) / loaded["samples"], 1),
                }
                point.update(measure(db, size, runner, workdir, tag))
                points.append(point)
                print(f"    {point}", flush=True)
            finally:
                if cluster is not None:
                    cluster.stop()
                if backend == "duckdb":
                    for p in workdir.glob(f"growth-{size}.duckdb*"):
                        p.unlink()
    print_curve(curve, sizes)
    return curve


def _p50(point: dict, key: str) -> float | None:
    s = point.get(key)
    return None if s is None else s["median"]


def print_curve(curve: dict, sizes: list[int]) -> None:
    for backend, points in curve.items():
        if not points:
            continue
        print(f"\ngrowth curve, {backend} (1,000 series; medians over the reps):")
        header = [
            "samples",
            "load s",
            "B/sample",
            "start-up s",
            "RSS start MiB",
            "RSS end MiB",
            "lastN=100 p50 ms",
            "hourly avg p50 ms",
            "ingest 16 conns /s",
        ]
        rows = [
            [
                f"{p['size']:,}",
                p["load_s"],
                p["bytes_per_sample"],
                p["startup_s"],
                p["rss_start_mib"],
                p["rss_end_mib"],
                _fmt(_p50(p, "lastN1")),
                _fmt(_p50(p, "hourly1")),
                _fmt(_p50(p, "ingest16"), 0),
            ]
            for p in points
        ]
        common.print_rows(header, rows)
        first, last = points[0], points[-1]
        if len(points) > 1:
            for key, label in (("lastN1", "lastN=100"), ("hourly1", "hourly avg")):
                a, b = _p50(first, key), _p50(last, key)
                if a and b:
                    print(
                        f"{'PASS' if b <= 2 * a else 'FAIL'}  {label} p50 flat within 2x: "
                        f"{a:.2f} ms at {first['size']:,} -> {b:.2f} ms at {last['size']:,} ({b / a:.1f}x)"
                    )
            ok = last["rss_end_mib"] <= 1.25 * first["rss_end_mib"] + 64
            print(
                f"{'PASS' if ok else 'FAIL'}  RSS does not grow with stored data: "
                f"{first['rss_end_mib']} MiB -> {last['rss_end_mib']} MiB"
            )
        rate = last["samples"] / max(last["load_s"], 0.1)
        for size in (10**8,):
            if size not in sizes:
                print(
                    f"estimate for {size:,} samples on {backend}: ~{size * last['bytes_per_sample'] / 2**30:.1f} GiB "
                    f"on disk, bulk load ~{size / rate / 60:.0f} min (at {rate:,.0f} samples/s measured at "
                    f"{last['samples']:,})"
                )


def _fmt(v, digits: int = 2) -> str:
    return "-" if v is None else f"{v:,.{digits}f}"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sizes", default="1M,10M,100M")
    ap.add_argument("--backends", default="duckdb")
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--duration", type=float, default=10.0)
    ap.add_argument("--warmup", type=float, default=2.0)
    args = ap.parse_args(argv)
    runner = loads.Runner(args.reps, args.duration, args.warmup, wrkrun.ensure_wrk() is not None)
    workdir = Path(tempfile.mkdtemp(prefix="tsdb-growth-"))
    try:
        run(args.sizes, args.backends, runner, workdir)
    finally:
        shutil.rmtree(workdir, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
