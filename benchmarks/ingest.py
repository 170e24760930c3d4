"""Ingest benchmark: Orion notifications per second, ours vs a bare FastAPI.

    .venv/bin/python benchmarks/ingest.py [--duration 10] [--connections 32] [--json FILE]
    .venv/bin/python benchmarks/ingest.py --backend postgresql [--workers 2]

1. Starts tsdb-service (one process) on a fresh temporary DuckDB file -- or,
   with ``--backend postgresql``, on a fresh database of a private PostgreSQL
   cluster started for the run (``initdb`` + ``pg_ctl``, 127.0.0.1, a free
   port) -- and waits for ``GET /health``.
2. Drives it with one-entity, normalized Orion notifications (a unique entity
   id and unique values per request) over ``--connections`` keep-alive
   connections: ``--warmup`` seconds, then ``--duration`` measured seconds.
3. Stops it with SIGTERM, opens the DuckDB file (or connects to PostgreSQL)
   and checks that every acknowledged notification's entity is stored (and
   with its value).
4. Does the same load against ``benchmarks/bare_app.py`` -- a FastAPI app
   that only parses the JSON -- under the same uvicorn settings: the ceiling.
5. Prints a table and the targets with PASS/FAIL; ``--json`` writes it all.

The exit status is 0 only if every check passes. Targets run one after the
other, never together: the machine has two cores, and the load generator
(``benchmarks/loadgen.py``, in its own process) already takes a share.
"""

from __future__ import annotations

import argparse
import math
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
import urllib.error
import urllib.request
from datetime import UTC, datetime, timedelta
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import common
from common import HOST, UVICORN_FLAGS, Server, bare_cmd, fmt, free_port, ours_cmd
from loadgen import LoadStats, run_load
from pgutil import BenchCluster

TENANT = "bench"

TARGET_RPS = 5000.0
TARGET_RATIO = 0.6
TARGET_P99_MS = 50.0

SANITY_SEQ = 10**9  # the one notification sent before the load (loadgen counts from 0)


# --------------------------------------------------------------------------
# the notifications


class NotificationFactory:
    """``seq -> request bytes``: one entity per notification, normalized
    format, a unique entity id and unique values derived from ``seq``.

    Entity ``urn:ngsi-ld:Sensor:<run>-<seq>`` carries ``temperature`` =
    seq + 0.25, ``humidity`` = seq % 100 + 0.5 and ``TimeInstant`` = base
    time + seq ms, so the store can be checked entity by entity afterwards.
    """

    BASE_TIME = datetime(2024, 5, 1, tzinfo=UTC)

    def __init__(self, port: int, run_id: str, tenant: str = TENANT, pool: int = 0):
        self.run_id = run_id
        self.pool = pool  # 0: a new entity per notification; N: N entities in turn
        self.head = (
            f"POST /v2/notify HTTP/1.1\r\n"
            f"Host: {HOST}:{port}\r\n"
            f"Content-Type: application/json\r\n"
            f"Fiware-Service: {tenant}\r\n"
            f"Fiware-ServicePath: /\r\n"
            f"Ngsiv2-AttrsFormat: normalized\r\n"
            f"Content-Length: "
        ).encode()
        self.body_fmt = (
            '{"subscriptionId":"5f1a2b3c4d5e6f7081920a1b","data":[{'
            '"id":"urn:ngsi-ld:Sensor:%s-%d","type":"Sensor",'
            '"temperature":{"type":"Number","value":%d.25,"metadata":{}},'
            '"humidity":{"type":"Number","value":%d.5,"metadata":{}},'
            '"TimeInstant":{"type":"DateTime","value":"%s","metadata":{}}}]}'
        )

    def entity_number(self, seq: int) -> int:
        return seq % self.pool if self.pool else seq

    def entity_id(self, seq: int) -> str:
        return f"urn:ngsi-ld:Sensor:{self.run_id}-{self.entity_number(seq)}"

    def body(self, seq: int) -> bytes:
        t = self.BASE_TIME + timedelta(milliseconds=seq)
        stamp = t.strftime("%Y-%m-%dT%H:%M:%S.") + f"{t.microsecond // 1000:03d}Z"
        return (self.body_fmt % (self.run_id, self.entity_number(seq), seq, seq % 100, stamp)).encode()

    def __call__(self, seq: int) -> bytes:
        body = self.body(seq)
        return self.head + str(len(body)).encode() + b"\r\n\r\n" + body


# --------------------------------------------------------------------------
# the servers


def post_notification(port: int, body: bytes) -> tuple[int, bytes]:
    """One notification to the server on ``port``: (status, body)."""
    req = urllib.request.Request(
        f"http://{HOST}:{port}/v2/notify",
        data=body,
        method="POST",
        headers={
            "Content-Type": "application/json",
            "Fiware-Service": TENANT,
            "Fiware-ServicePath": "/",
            "Ngsiv2-AttrsFormat": "normalized",
        },
    )
    try:
        with urllib.request.urlopen(req, timeout=10) as resp:
            return resp.status, resp.read()
    except urllib.error.HTTPError as exc:
        return exc.code, exc.read()


# --------------------------------------------------------------------------
# one run


def measure(target: Server, factory: NotificationFactory, args) -> tuple[LoadStats, dict]:
    """Sanity request, then the load; returns loadgen stats and extras."""
    status, body = post_notification(target.port, factory.body(SANITY_SEQ))
    if not 200 <= status < 300:
        raise RuntimeError(f"{target.name}: sanity notification answered {status}: {body[:500]!r}\n{target.log_tail()}")
    cpu0, t0 = target.cpu_seconds(), time.monotonic()
    stats = run_load(
        HOST,
        target.port,
        factory,
        connections=args.connections,
        duration=args.duration,
        warmup=args.warmup,
        processes=args.processes,
    )
    cpu1, t1 = target.cpu_seconds(), time.monotonic()
    extras = {"server_cpu_pct": 100.0 * (cpu1 - cpu0) / (t1 - t0) if t1 > t0 else math.nan, "sanity_acked": 1}
    return stats, extras


def count_stored_duckdb(db_path: Path, prefix: str, modulus: int) -> tuple[int, int, int]:
    """(notifications, samples, notifications with the right temperature) in the DuckDB file."""
    import duckdb

    con = duckdb.connect(str(db_path), read_only=True)
    try:
        entities, samples = con.execute(
            """
            SELECT count(*) FILTER (WHERE s.attr = 'temperature'), count(*)
            FROM series s JOIN samples_all a ON a.sid = s.sid
            WHERE s.tenant = ? AND starts_with(s.entity_id, ?)
            """,
            [TENANT, prefix],
        ).fetchone()
        good_temp = con.execute(
            r"""
            SELECT count(DISTINCT a.num)
            FROM series s JOIN samples_all a ON a.sid = s.sid
            WHERE s.tenant = ? AND starts_with(s.entity_id, ?) AND s.attr = 'temperature'
              AND CAST(a.num - 0.25 AS BIGINT) % ? = CAST(regexp_extract(s.entity_id, '-(\d+)$', 1) AS BIGINT)
            """,
            [TENANT, prefix, modulus],
        ).fetchone()[0]
    finally:
        con.close()
    return entities, samples, good_temp


def count_stored_postgres(url: str, prefix: str, modulus: int) -> tuple[int, int, int]:
    """The same counts, read from PostgreSQL (tables ``series`` and ``samples``)."""
    import psycopg

    with psycopg.connect(url) as conn:
        entities, samples = conn.execute(
            """
            SELECT count(*) FILTER (WHERE s.attr = 'temperature'), count(*)
            FROM series s JOIN samples a ON a.sid = s.sid
            WHERE s.tenant = %s AND starts_with(s.entity_id, %s)
            """,
            [TENANT, prefix],
        ).fetchone()
        good_temp = conn.execute(
            r"""
            SELECT count(DISTINCT a.num)
            FROM series s JOIN samples a ON a.sid = s.sid
            WHERE s.tenant = %s AND starts_with(s.entity_id, %s) AND s.attr = 'temperature'
              AND CAST(a.num - 0.25 AS BIGINT) %% %s = CAST(substring(s.entity_id FROM '-(\d+)$') AS BIGINT)
            """,
            [TENANT, prefix, modulus],
        ).fetchone()[0]
    return entities, samples, good_temp


def verify_store(db: Path | str, factory: NotificationFactory, acked: int, unacked: int) -> dict:
    """Count the stored notifications (one temperature sample each, a unique
    value seq + 0.25 on entity number seq mod pool) and check their values."""
    prefix = f"urn:ngsi-ld:Sensor:{factory.run_id}-"
    modulus = factory.pool or 2**62
    if isinstance(db, str) and db.startswith("postgresql://"):
        entities, samples, good_temp = count_stored_postgres(db, prefix, modulus)
    else:
        entities, samples, good_temp = count_stored_duckdb(Path(db), prefix, modulus)
    ok = acked <= entities <= acked + unacked and good_temp == entities
    return {
        "stored_entities": entities,
        "stored_samples": samples,
        "entities_with_correct_temperature": good_temp,
        "acknowledged": acked,
        "unacknowledged": unacked,
        "lost": max(0, acked - entities),
        "ok": ok,
    }


# --------------------------------------------------------------------------
# report


def print_table(rows: dict[str, dict]) -> None:
    cols = [
        "target",
        "requests",
        "non-2xx",
        "errors",
        "notif/s",
        "p50 ms",
        "p90 ms",
        "p99 ms",
        "max ms",
        "srv CPU%",
        "gen CPU%",
    ]
    table = []
    for name, r in rows.items():
        s = r["load"]
        table.append(
            [
                name,
                f"{s['requests']:,}",
                f"{s['non_2xx']:,}",
                f"{s['errors']:,}",
                fmt(s["rps"], 0),
                fmt(s["p50_ms"], 2),
                fmt(s["p90_ms"], 2),
                fmt(s["p99_ms"], 2),
                fmt(s["max_ms"], 1),
                fmt(r.get("server_cpu_pct"), 0),
                fmt(s["generator_cpu_pct"], 0),
            ]
        )
    common.print_rows(cols, table, widths=[22, 9, 8, 7, 9, 8, 8, 8, 8, 9, 9])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--duration", type=float, default=10.0, help="measured seconds per target (default 10)")
    ap.add_argument("--warmup", type=float, default=2.0, help="warmup seconds before measuring (default 2)")
    ap.add_argument("--connections", type=int, default=32, help="concurrent keep-alive connections (default 32)")
    ap.add_argument("--processes", type=int, default=1, help="load generator processes (default 1)")
    ap.add_argument("--json", type=Path, metavar="FILE", help="also write the results as JSON")
    ap.add_argument("--targets", default="ours,bare", help="comma list of: ours, bare (default both)")
    ap.add_argument("--server-env", action="append", default=[], metavar="KEY=VALUE", help="extra env for our server")
    ap.add_argument("--start-timeout", type=float, default=60.0, help="seconds to wait for a server to be ready")
    ap.add_argument(
        "--entities",
        type=int,
        default=1000,
        help="entities notified in turn (default 1000, as a deployment has); 0 = a new entity per notification",
    )
    ap.add_argument("--keep", action="store_true", help="keep the temp dir (DuckDB file, server logs)")
    ap.add_argument(
        "--backend",
        choices=("duckdb", "postgresql"),
        default="duckdb",
        help="store behind our server: a temp DuckDB file (default) or a private PostgreSQL cluster",
    )
    ap.add_argument(
        "--workers",
        type=int,
        default=1,
        help="uvicorn workers for our server (PostgreSQL only; default 1). The bare ceiling keeps 1.",
    )
    args = ap.parse_args(argv)
    if args.workers < 1 or (args.workers > 1 and args.backend != "postgresql"):
        ap.error("--workers > 1 needs --backend postgresql (a DuckDB file belongs to one process)")

    targets = [t.strip() for t in args.targets.split(",") if t.strip()]
    if not targets or set(targets) - {"ours", "bare"}:
        ap.error("--targets takes ours and/or bare")

    workdir = Path(tempfile.mkdtemp(prefix="tsdb-ingest-bench-"))
    db_path = workdir / "ingest.duckdb"
    run_id = f"{int(time.time())}{os.getpid() % 1000:03d}"
    results: dict = {
        "benchmark": "ingest",
        "started_at": datetime.now(UTC).isoformat(timespec="seconds"),
        "config": {
            "backend": args.backend,
            "workers": args.workers,
            "duration_s": args.duration,
            "warmup_s": args.warmup,
            "connections": args.connections,
            "loadgen_processes": args.processes,
            "uvicorn_flags": UVICORN_FLAGS,
            "notification": "1 entity, normalized, temperature + humidity + TimeInstant",
        },
        "machine": common.machine(),
        "targets": {},
    }
    rows: dict[str, dict] = {}
    failures: list[str] = []
    ours_name = "tsdb-service" if args.backend == "duckdb" else "tsdb-service on PostgreSQL"
    if args.workers > 1:
        ours_name += f" ({args.workers} workers)"
    print(
        f"ingest benchmark ({args.backend}): {args.connections} connections, warmup {args.warmup:g} s, "
        f"measure {args.duration:g} s, {os.cpu_count()} CPUs; work dir {workdir}",
        flush=True,
    )
    cluster: BenchCluster | None = None
    try:
        if "ours" in targets:
            port = free_port()
            db: Path | str = db_path
            if args.backend == "postgresql":
                print("- starting a private PostgreSQL cluster ...", flush=True)
                cluster = BenchCluster("ingest").start()
                db = cluster.url
                results["config"]["postgresql_version"] = cluster.version
            env = common.server_env(args.server_env, keep_tsdb=True)
            ours = Server(ours_name, ours_cmd(db, port, args.workers), port, workdir / "tsdb-service.log", env)
            print(f"- {ours_name} on :{port} ({db_path.name if cluster is None else db}) ...", flush=True)
            try:
                ours.start(args.start_timeout)
                factory = NotificationFactory(port, run_id, pool=args.entities)
                db_cpu0, t0 = (cluster.cpu_seconds() if cluster else math.nan), time.monotonic()
                stats, extras = measure(ours, factory, args)
                db_cpu1, t1 = (cluster.cpu_seconds() if cluster else math.nan), time.monotonic()
                code, stop_s = ours.terminate(60.0)
            finally:
                ours.kill()
            acked = stats.total_ok + extras["sanity_acked"]
            unacked = stats.total_errors + stats.total_non_2xx
            verification = verify_store(db, factory, acked, unacked)
            row = {
                "load": stats.to_dict(),
                "server_cpu_pct": extras["server_cpu_pct"],
                "exit_code": code,
                "sigterm_exit_s": round(stop_s, 3),
                "verification": verification,
                "db_bytes": (
                    cluster.database_bytes()
                    if cluster
                    else sum(p.stat().st_size for p in workdir.glob("ingest.duckdb*"))
                ),
            }
            if cluster is not None:
                # the PostgreSQL server's own CPU (backends + background processes), same window
                row["db_cpu_pct"] = 100.0 * (db_cpu1 - db_cpu0) / (t1 - t0) if t1 > t0 else math.nan
            rows[ours_name] = row
            results["targets"]["ours"] = row
            if code not in (0, -signal.SIGTERM):  # uvicorn re-raises SIGTERM after draining
                failures.append(f"tsdb-service exited with code {code} after SIGTERM")
                print(ours.log_tail(), flush=True)
        if "bare" in targets:
            port = free_port()
            env = common.server_env(keep_tsdb=True)
            bare = Server(
                "bare FastAPI", bare_cmd(port), port, workdir / "bare.log", env, "/v2/notify", common.accept_any_answer
            )
            print(f"- bare FastAPI on :{port} ...", flush=True)
            try:
                bare.start(args.start_timeout)
                stats, extras = measure(bare, NotificationFactory(port, run_id, pool=args.entities), args)
                code, stop_s = bare.terminate(60.0)
            finally:
                bare.kill()
            row = {"load": stats.to_dict(), "server_cpu_pct": extras["server_cpu_pct"], "exit_code": code}
            rows["bare FastAPI (ceiling)"] = row
            results["targets"]["bare"] = row
    except (RuntimeError, subprocess.CalledProcessError, OSError) as exc:
        detail = getattr(exc, "stderr", None) or ""
        print(f"\nERROR: {exc}\n{detail}", file=sys.stderr)
        results["error"] = str(exc)
        failures.append(str(exc))
    finally:
        if cluster is not None:
            cluster.stop()

    print()
    if rows:
        print_table(rows)
    checks = []
    ours_row, bare_row = results["targets"].get("ours"), results["targets"].get("bare")
    if ours_row and "db_cpu_pct" in ours_row:
        print(
            f"\nPostgreSQL server CPU during the measured window: {fmt(ours_row['db_cpu_pct'], 0)}% "
            "(on top of srv CPU%; all on the same cores)"
        )
    ratio = None
    if ours_row and bare_row and bare_row["load"]["rps"]:
        ratio = ours_row["load"]["rps"] / bare_row["load"]["rps"]
        results["ratio"] = ratio
        ours_rps, bare_rps = ours_row["load"]["rps"], bare_row["load"]["rps"]
        print(f"\nratio = ours / bare ceiling = {ours_rps:,.0f} / {bare_rps:,.0f} = {ratio:.2f}")
    if ours_row:
        s, v = ours_row["load"], ours_row["verification"]
        checks.append(("throughput (notif/s)", f">= {TARGET_RPS:,.0f}", fmt(s["rps"], 0), s["rps"] >= TARGET_RPS))
        if ratio is not None:
            checks.append(("ratio ours / bare", f">= {TARGET_RATIO:.2f}", f"{ratio:.2f}", ratio >= TARGET_RATIO))
        p99 = s["p99_ms"]
        checks.append(
            ("p99 latency (ms)", f"<= {TARGET_P99_MS:g}", fmt(p99, 2), p99 is not None and p99 <= TARGET_P99_MS)
        )
        checks.append(("non-2xx + errors", "= 0", f"{s['non_2xx'] + s['errors']}", s["non_2xx"] + s["errors"] == 0))
        checks.append(
            (
                "stored = acknowledged",
                f"{v['acknowledged']:,} acked",
                f"{v['stored_entities']:,} stored",
                v["ok"],
            )
        )
        print(
            f"\nstore check (after SIGTERM, exit code {ours_row['exit_code']}, {ours_row['sigterm_exit_s']} s): "
            f"{v['stored_entities']:,} notifications stored, {v['acknowledged']:,} notifications acknowledged "
            f"(incl. 1 sanity), {v['lost']:,} lost, {v['unacknowledged']:,} unacknowledged; "
            f"{v['entities_with_correct_temperature']:,} with the right temperature; {v['stored_samples']:,} samples"
        )
    if checks:
        print()
        print(f"{'check':<24}{'target':>18}{'measured':>16}  result")
        for name, want, got, ok in checks:
            print(f"{name:<24}{want:>18}{got:>16}  {'PASS' if ok else 'FAIL'}")
    results["checks"] = [{"check": n, "target": w, "measured": g, "pass": bool(ok)} for n, w, g, ok in checks]
    for name, _, _, ok in checks:
        if not ok:
            failures.append(f"check failed: {name}")
    results["pass"] = not failures

    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        common.write_json(args.json, results)
        print(f"results written to {args.json}")
    if args.keep:
        print(f"kept {workdir}")
    else:
        shutil.rmtree(workdir, ignore_errors=True)
    if failures:
        print("\nFAIL: " + "; ".join(f.splitlines()[0] for f in failures), file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
