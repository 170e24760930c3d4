"""Long windows (issue 38): a month of telemetry in one Grafana panel.

    .venv/bin/python benchmarks/long_windows.py                           # DuckDB 30 days, PostgreSQL 10 days
    .venv/bin/python benchmarks/long_windows.py --backends duckdb --days 30
    .venv/bin/python benchmarks/long_windows.py --days 1 --entities 2     # a smoke run (seconds)

For each backend, on a fresh database:

1. bulk-loads ``--entities`` (20) entities x 5 numeric attributes at 1 Hz over
   ``--days`` days (DuckDB 30, PostgreSQL 10: 260M and 86M samples) in the
   database itself, as ``growth.py`` does (DuckDB: ``INSERT ... SELECT`` from
   ``range()`` into the sorted table, in (sid, t) order, then the rollups by
   ``tsdb-service rollups rebuild``'s work; PostgreSQL: ``generate_series``,
   rolled up by its trigger, the rollups merged as the service's merger
   would, then ``VACUUM (ANALYZE)``); the samples of one entity
   at one second share a row id, as the service writes them. Entity 0's
   ``speed`` holds one spike (1000.0) in the middle of the window, every
   other sample is below 100;
2. starts the server and measures, one request at a time:
   * **panel**: 20 entities x 1 attribute (``speed``) over the whole window at
     1,000 points, through Infinity (``/grafana/infinity/series``) and through
     SimpleJSON (``/query``, ``maxDataPoints`` 1,000, ``intervalMs`` span/1,000):
     p50, p99, the server's RSS before and after (memory flat), and whether
     every entity's first and last bucket are there (the whole window);
   * **panel under ingest**: the Infinity panel every 5 s while a paced
     client sends 1,000 notifications/s (the ingest tenant, other series):
     the panel's p99 against its idle p50, and the ingest rate reached with
     and without the panel;
   * **24 h raw**: the last 24 hours of one attribute at 1 s (86,400
     points, ``max_points`` 86,400: drawn as stored, no buckets);
   * **spike**: the panel in the min-max mode shows the one sample of 1000.0.

Then one table per backend with the issue's targets, PASS or FAIL. Run it
on an idle machine: the figures mean nothing while other work shares the
cores. The 150 ms panel target assumes rollups (minute and hour tables);
over raw samples it is expected to be missed on the full data.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import multiprocessing
import shutil
import statistics
import sys
import tempfile
import time
import urllib.request
from datetime import UTC, datetime, timedelta
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import common
import lawnmower

TENANT = "benchlong"
ATTRS = ("batteryLevel", "speed", "bladeSpeed", "cutHeight", "motorTemperature")
START = datetime(2024, 5, 1, tzinfo=UTC)
SPIKE_VALUE = 1000.0
POINTS = 1000
DAY_S = 86_400
TARGETS_MS = {"duckdb": 150.0, "postgresql": 500.0}
RAW_24H_TARGET_MS = 300.0


def entity_id(e: int) -> str:
    return f"urn:ngsi-ld:Lawnmower:w{e:03d}"


def spike_second(days: int) -> int:
    return days * DAY_S // 2 + 12_345


# --- bulk load -------------------------------------------------------------------------------


def _series(entities: int) -> list[list]:
    cols: list[list] = [[], [], [], [], [], []]
    for e in range(entities):
        for a, name in enumerate(ATTRS):
            row = (e * len(ATTRS) + a + 1, TENANT, "/", entity_id(e), "Lawnmower", name)
            for col, value in zip(cols, row, strict=True):
                col.append(value)
    return cols


def _value_sql(spike: int, k: str, mod: str = "%") -> str:
    """Below 100 everywhere, but entity 0's speed at ``spike`` (``mod``: ``%%``
    where ``%`` starts a placeholder)."""
    return f"CASE WHEN e = 0 AND a = 1 AND {k} = {spike} THEN {SPIKE_VALUE} ELSE e + a + ({k} {mod} 3600) / 100.0 END"


def load_duckdb(path: str, entities: int, days: int) -> dict:
    import duckdb

    from tsdb_service.storage.duckdb.store import DuckDBStore

    DuckDBStore(path).close()  # the schema
    seconds = days * DAY_S
    con = duckdb.connect(path)
    t0 = time.perf_counter()
    try:
        con.execute(
            "INSERT INTO series BY NAME SELECT unnest($1::INTEGER[]) AS sid, unnest($2::VARCHAR[]) AS tenant, "
            "unnest($3::VARCHAR[]) AS service_path, unnest($4::VARCHAR[]) AS entity_id, "
            "unnest($5::VARCHAR[]) AS entity_type, unnest($6::VARCHAR[]) AS attr",
            _series(entities),
        )
        for e in range(entities):  # one entity (5 series) per statement: its ORDER BY stays in memory
            con.execute(
                f"""INSERT INTO samples BY NAME
                SELECT (kk * {entities} + e + 1)::BIGINT AS rid, (e * {len(ATTRS)} + a + 1)::INTEGER AS sid,
                       ((kk * {entities} + e) * {len(ATTRS)} + a + 1)::BIGINT AS iid,
                       TIMESTAMP '2024-05-01' + to_seconds(kk) AS t, 1::UTINYINT AS kind, 'Number' AS atype,
                       ({_value_sql(spike_second(days), "kk")})::DOUBLE AS num
                FROM (SELECT ? AS e) r1, range({len(ATTRS)}) r2(a), range(?) r3(kk)
                ORDER BY sid, t""",
                [e, seconds],
            )
            print(f"    entity {e + 1}/{entities} loaded", flush=True)
        con.execute("CHECKPOINT")
    finally:
        con.close()
    loaded = round(time.perf_counter() - t0, 1)
    # Loaded behind the writer's back: the rollups come from the rebuild command's work
    # (PostgreSQL's trigger rolls up its load as it goes).
    from tsdb_service.commands.rollups import rebuild_rollups

    t0 = time.perf_counter()
    store = DuckDBStore(path)
    try:
        rebuild_rollups(store)
        store.compact()
    finally:
        store.close()
    rolled = round(time.perf_counter() - t0, 1)
    print(f"    rollups built in {rolled} s", flush=True)
    return {"samples": entities * len(ATTRS) * seconds, "load_s": loaded, "rollups_s": rolled}


def load_postgres(url: str, entities: int, days: int) -> dict:
    import psycopg

    from tsdb_service.storage.postgres.store import PostgresStore

    PostgresStore(url).close()  # the schema
    seconds = days * DAY_S
    t0 = time.perf_counter()
    with psycopg.connect(url, autocommit=True) as conn:
        conn.execute(
            "INSERT INTO series (sid, tenant, service_path, entity_id, entity_type, attr) "
            "SELECT * FROM unnest(%s::int[], %s::text[], %s::text[], %s::text[], %s::text[], %s::text[])",
            _series(entities),
        )
        conn.execute("SELECT setval(pg_get_serial_sequence('series', 'sid'), %s)", [entities * len(ATTRS)])
        day = DAY_S
        for e in range(entities):
            for d in range(days):  # a day of one entity per statement
                conn.execute(
                    f"""INSERT INTO samples (rid, sid, t, kind, atype, num)
                    SELECT kk::bigint * {entities} + e + 1, e * {len(ATTRS)} + a + 1,
                           TIMESTAMP '2024-05-01' + make_interval(secs => kk), 1, 'Number',
                           {_value_sql(spike_second(days), "kk", "%%")}
                    FROM (SELECT %s::int AS e) r1, generate_series(0, {len(ATTRS) - 1}) a,
                         generate_series(%s::int, %s::int) kk
                    ORDER BY 2, 3""",
                    [e, d * day, (d + 1) * day - 1],
                )
            print(f"    entity {e + 1}/{entities} loaded", flush=True)
        conn.execute("SELECT setval('sample_rid_seq', %s)", [seconds * entities])
        conn.execute("INSERT INTO untimed_series (sid) SELECT sid FROM series ON CONFLICT DO NOTHING")
    loaded = round(time.perf_counter() - t0, 1)
    # The trigger rolled the load up into rollups_hot; merge it into the levels (what the
    # service's merger would do in its first minutes) so the panel reads merged rows.
    t0 = time.perf_counter()
    store = PostgresStore(url)
    try:
        store.compact()
    finally:
        store.close()
    with psycopg.connect(url, autocommit=True) as conn:
        for table in ("samples", "rollups_minute", "rollups_hour", "rollups_hot"):
            conn.execute(f"VACUUM (ANALYZE) {table}")
        conn.execute("CHECKPOINT")
    merged = round(time.perf_counter() - t0, 1)
    print(f"    rollups merged in {merged} s", flush=True)
    return {"samples": entities * len(ATTRS) * seconds, "load_s": loaded, "rollups_s": merged}


# --- requests --------------------------------------------------------------------------------


def _ms(moment: datetime) -> int:
    return int(moment.timestamp() * 1000)


def timed(request: urllib.request.Request) -> tuple[float, bytes, dict]:
    t0 = time.perf_counter()
    with urllib.request.urlopen(request, timeout=300) as answer:
        body = answer.read()
        headers = dict(answer.headers)
    return (time.perf_counter() - t0) * 1000, body, headers


def infinity_panel(url: str, start: datetime, end: datetime, agg: str = "auto") -> urllib.request.Request:
    query = (
        f"type=Lawnmower&attrs=v=speed&from={_ms(start)}&to={_ms(end)}&max_points={POINTS}"
        f"&interval_ms={max(1, (_ms(end) - _ms(start)) // POINTS)}&agg={agg}"
    )
    return urllib.request.Request(f"{url}/grafana/infinity/series?{query}", headers=lawnmower.query_headers(TENANT))


def simplejson_panel(url: str, start: datetime, end: datetime) -> urllib.request.Request:
    body = {
        "range": {"from": start.isoformat(), "to": end.isoformat()},
        "maxDataPoints": POINTS,
        "intervalMs": max(1, (_ms(end) - _ms(start)) // POINTS),
        "targets": [{"target": "*/speed", "refId": "A", "payload": {"type": "Lawnmower", "format": "dataframe"}}],
    }
    headers = {**lawnmower.query_headers(TENANT), "Content-Type": "application/json"}
    return urllib.request.Request(f"{url}/grafana/simplejson/query", json.dumps(body).encode(), headers)


def whole_window_infinity(body: bytes, start: datetime, end: datetime, entities: int, width_ms: int) -> bool:
    """Every entity's first point in the window's first bucket and its last in its last."""
    first: dict[str, int] = {}
    last: dict[str, int] = {}
    for row in json.loads(body):
        t = _ms(datetime.fromisoformat(row["time"].replace("Z", "+00:00")))
        first[row["entity"]] = min(first.get(row["entity"], t), t)
        last[row["entity"]] = max(last.get(row["entity"], t), t)
    return (
        len(first) == entities
        and all(t <= _ms(start) + width_ms for t in first.values())
        and all(t >= _ms(end) - 2 * width_ms for t in last.values())
    )


def whole_window_simplejson(body: bytes, start: datetime, end: datetime, entities: int, width_ms: int) -> bool:
    frames = json.loads(body)
    times = [f["fields"][0]["values"] for f in frames]
    return len(frames) == entities and all(
        ts and ts[0] <= _ms(start) + width_ms and ts[-1] >= _ms(end) - 2 * width_ms for ts in times
    )


def percentile(values: list[float], q: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, round(q * (len(ordered) - 1)))]


def measure_panel(server, make, check, reps: int) -> dict:
    rss_before = server.rss_bytes() or 0
    timed(make())  # the first answer warms the catalog and the plans
    times, whole, width = [], True, None
    for _ in range(reps):
        ms, body, headers = timed(make())
        times.append(ms)
        width = int(headers.get("X-Tsdb-Bucket-Ms", headers.get("x-tsdb-bucket-ms", "0")) or 0)
        whole = whole and check(body, width)
    return {
        "p50_ms": round(statistics.median(times), 1),
        "p99_ms": round(percentile(times, 0.99), 1),
        "rss_before_mib": round(rss_before / 2**20),
        "rss_after_mib": round((server.rss_bytes() or 0) / 2**20),
        "whole_window": whole,
        "bucket_ms": width,
    }


# --- paced ingest ------------------------------------------------------------------------------


def _ingest_process(url: str, rate: float, seconds: float, out) -> None:
    """Send ``rate`` notifications/s for ``seconds`` (8 keep-alive connections,
    each on its own schedule); put (sent, ok, achieved rate) on ``out``."""
    from urllib.parse import urlsplit

    parts = urlsplit(url)
    hdrs = lawnmower.headers(lawnmower.INGEST_TENANT)
    head = (
        f"POST /v2/notify HTTP/1.1\r\nHost: {parts.hostname}:{parts.port}\r\n"
        + "".join(f"{k}: {v}\r\n" for k, v in hdrs.items())
        + "Content-Length: "
    ).encode()
    connections = 8
    run = f"lw{int(time.time())}"

    async def one(c: int, t0: float, counts: list[int]) -> None:
        reader, writer = await asyncio.open_connection(parts.hostname, parts.port)
        i = 0
        while True:
            due = t0 + (i * connections + c) / rate
            if due > t0 + seconds:
                break
            delay = due - time.monotonic()
            if delay > 0:
                await asyncio.sleep(delay)
            body = lawnmower.ingest_body(run, i * connections + c, 1000)
            writer.write(head + str(len(body)).encode() + b"\r\n\r\n" + body)
            status = await reader.readline()
            length = 0
            while (line := await reader.readline()) not in (b"\r\n", b""):
                if line.lower().startswith(b"content-length:"):
                    length = int(line.split(b":")[1])
            if length:
                await reader.readexactly(length)
            counts[0] += 1
            counts[1] += status.split(b" ")[1] in (b"200", b"204")
            i += 1
        writer.close()

    async def main() -> None:
        counts = [0, 0]
        t0 = time.monotonic()
        await asyncio.gather(*(one(c, t0, counts) for c in range(connections)))
        out.put((counts[0], counts[1], counts[1] / (time.monotonic() - t0)))

    asyncio.run(main())


def ingest(url: str, rate: float, seconds: float):
    queue: multiprocessing.Queue = multiprocessing.Queue()
    proc = multiprocessing.Process(target=_ingest_process, args=(url, rate, seconds, queue))
    proc.start()
    return proc, queue


def under_ingest(server, start: datetime, end: datetime, rate: float, seconds: float, idle_p50: float) -> dict:
    proc, queue = ingest(server.url, rate, seconds)
    sent, ok, alone = None, None, None
    proc.join()
    sent, ok, alone = queue.get()
    proc, queue = ingest(server.url, rate, seconds)
    panel = []
    t_end = time.monotonic() + seconds
    while time.monotonic() < t_end - 1:
        tick = time.monotonic()
        panel.append(timed(infinity_panel(server.url, start, end))[0])
        time.sleep(max(0.0, 5.0 - (time.monotonic() - tick)))
    proc.join()
    sent2, ok2, with_panel = queue.get()
    return {
        "ingest_alone_per_s": round(alone),
        "ingest_with_panel_per_s": round(with_panel),
        "ingest_errors": (sent - ok) + (sent2 - ok2),
        "panel_p99_ms": round(percentile(panel, 0.99), 1) if panel else None,
        "panel_runs": len(panel),
        "idle_p50_ms": idle_p50,
    }


# --- one backend -------------------------------------------------------------------------------


def run_backend(backend: str, entities: int, days: int, reps: int, ingest_s: float, workdir: Path) -> dict:
    end = START + timedelta(days=days) - timedelta(milliseconds=1)
    cluster = None
    try:
        if backend == "postgresql":
            from pgutil import BenchCluster

            cluster = BenchCluster("longwin").start()
            db = cluster.url
            loaded = load_postgres(db, entities, days)
        else:
            db = str(workdir / "longwin.duckdb")
            loaded = load_duckdb(db, entities, days)
        print(f"    loaded {loaded}", flush=True)
        port = common.free_port()
        server = common.spawned(f"longwin-{backend}", common.ours_cmd(db, port), port, workdir)
        server.start(timeout=900)
        try:
            url = server.url
            out: dict = {"backend": backend, "days": days, "entities": entities, **loaded}
            out["infinity"] = measure_panel(
                server,
                lambda: infinity_panel(url, START, end),
                lambda body, w: whole_window_infinity(body, START, end, entities, w),
                reps,
            )
            print(f"    infinity panel {out['infinity']}", flush=True)
            out["simplejson"] = measure_panel(
                server,
                lambda: simplejson_panel(url, START, end),
                lambda body, w: whole_window_simplejson(body, START, end, entities, w),
                reps,
            )
            print(f"    simplejson panel {out['simplejson']}", flush=True)
            day_ago = end - timedelta(days=1) + timedelta(milliseconds=1)
            raw = urllib.request.Request(
                f"{url}/grafana/infinity/series?id={entity_id(0)}&attrs=v=speed&from={_ms(day_ago)}&to={_ms(end)}"
                f"&max_points=86400",
                headers=lawnmower.query_headers(TENANT),
            )
            timed(raw)
            runs = [timed(raw) for _ in range(max(3, reps // 4))]
            out["raw24h"] = {
                "p50_ms": round(statistics.median(r[0] for r in runs), 1),
                "points": len(json.loads(runs[0][1])),
                "bucket": runs[0][2].get("X-Tsdb-Bucket") or runs[0][2].get("x-tsdb-bucket"),
            }
            print(f"    24 h raw {out['raw24h']}", flush=True)
            _, body, _ = timed(infinity_panel(url, START, end, agg="minmax"))
            out["spike_shown"] = any(row.get("v") == SPIKE_VALUE for row in json.loads(body))
            out["under_ingest"] = under_ingest(server, START, end, 1000.0, ingest_s, out["infinity"]["p50_ms"])
            print(f"    under ingest {out['under_ingest']}", flush=True)
        finally:
            server.stop()
        return out
    finally:
        if cluster is not None:
            cluster.stop()
        for path in workdir.glob("longwin.duckdb*"):
            shutil.rmtree(path) if path.is_dir() else path.unlink()


def verdicts(result: dict) -> list[tuple[str, str, str]]:
    backend = result["backend"]
    target = TARGETS_MS[backend]
    rows = []
    for face in ("infinity", "simplejson"):
        panel = result[face]
        rows.append(
            (
                f"panel via {face}: p50 <= {target:.0f} ms",
                f"{panel['p50_ms']} ms (p99 {panel['p99_ms']})",
                "PASS" if panel["p50_ms"] <= target else "FAIL",
            )
        )
        rows.append(
            (
                f"panel via {face}: every first and last bucket present",
                str(panel["whole_window"]),
                "PASS" if panel["whole_window"] else "FAIL",
            )
        )
        flat = panel["rss_after_mib"] <= panel["rss_before_mib"] * 1.1 + 32
        rows.append(
            (
                f"panel via {face}: memory flat",
                f"{panel['rss_before_mib']} -> {panel['rss_after_mib']} MiB",
                "PASS" if flat else "FAIL",
            )
        )
    busy = result["under_ingest"]
    p99, idle = busy["panel_p99_ms"], busy["idle_p50_ms"]
    rows.append(
        (
            "panel every 5 s under 1,000 notifications/s: p99 <= 2x idle p50",
            f"{p99} ms vs {idle} ms",
            "PASS" if p99 is not None and p99 <= 2 * idle else "FAIL",
        )
    )
    alone, both = busy["ingest_alone_per_s"], busy["ingest_with_panel_per_s"]
    rows.append(
        (
            "ingest unchanged within 10 % with the panel",
            f"{both}/s vs {alone}/s alone ({busy['ingest_errors']} errors)",
            "PASS" if both >= 0.9 * alone and busy["ingest_errors"] == 0 else "FAIL",
        )
    )
    raw = result["raw24h"]
    rows.append(
        (
            f"last 24 h of one attribute at 1 s (86,400 points, raw) <= {RAW_24H_TARGET_MS:.0f} ms",
            f"{raw['p50_ms']} ms, {raw['points']:,} points, bucket {raw['bucket']}",
            "PASS"
            if raw["p50_ms"] <= RAW_24H_TARGET_MS and raw["points"] == 86_400 and raw["bucket"] == "raw"
            else "FAIL",
        )
    )
    rows.append(
        ("a one-sample spike is visible in min-max mode at 1,000 points", str(result["spike_shown"]),
         "PASS" if result["spike_shown"] else "FAIL")
    )  # fmt: skip
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--backends", default="duckdb,postgresql")
    ap.add_argument("--entities", type=int, default=20)
    ap.add_argument("--days", type=int, default=None, help="days of data (default: DuckDB 30, PostgreSQL 10)")
    ap.add_argument("--reps", type=int, default=40, help="panel requests measured per face")
    ap.add_argument("--ingest-seconds", type=float, default=30.0, help="each paced ingest run")
    ap.add_argument("--json", metavar="FILE", help="also write the results as JSON")
    args = ap.parse_args(argv)
    workdir = Path(tempfile.mkdtemp(prefix="tsdb-longwin-"))
    results = []
    try:
        for backend in [b.strip() for b in args.backends.split(",") if b.strip()]:
            days = args.days or (30 if backend == "duckdb" else 10)
            print(
                f"- long windows, {backend}: {args.entities} entities x 5 attributes x {days} days at 1 Hz", flush=True
            )
            results.append(run_backend(backend, args.entities, days, args.reps, args.ingest_seconds, workdir))
    finally:
        shutil.rmtree(workdir, ignore_errors=True)
    print(f"\nmachine: {common.machine()}, load {common.load_text()}")
    for result in results:
        print(
            f"\n{result['backend']}: {result['samples']:,} samples ({result['entities']} x 5 x {result['days']} days), "
            f"loaded in {result['load_s']} s, rollups {result['rollups_s']} s"
        )
        common.print_rows(["target", "measured", "verdict"], [list(row) for row in verdicts(result)])
    if args.json:
        common.write_json(args.json, results)
    return 0


if __name__ == "__main__":
    sys.exit(main())
