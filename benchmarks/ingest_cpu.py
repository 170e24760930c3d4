"""CPU per stored notification and per stored sample of the ingest path, per process.

    .venv/bin/python benchmarks/ingest_cpu.py                                   # DuckDB, 16 and 64 connections
    .venv/bin/python benchmarks/ingest_cpu.py --server-env TSDB_INGEST_LOG=0    # another configuration
    .venv/bin/python benchmarks/ingest_cpu.py --backend postgresql --serve-arg=--workers=2
    .venv/bin/python benchmarks/ingest_cpu.py --tree /tmp/before --label before # another checkout, same load

Requests per second and latencies measured on a machine other work shares
say little; the CPU a notification costs barely depends on who else runs.
This starts our server (as ``compare.py`` does: a temporary DuckDB file, or
a fresh database of a private PostgreSQL cluster), warms it up with
``compare.py``'s ingest load through wrk (1,000 Lawnmower entities in turn,
so every series exists before the measurement), then for each connection
count runs ``--reps`` windows of ``--seconds`` and reads, before and after
each, the user + system CPU of every process of the server (``/proc``,
through psutil: the serving process and any it started; of the serving
process's main thread, its event loop, apart), of the database server on
PostgreSQL, and of wrk. It prints, per window, the CPU
milliseconds per acknowledged notification of each process and in all, and
per stored sample (a notification stores 6: ``TimeInstant`` and five
attributes), and on DuckDB how many samples each transaction of the ingest
log's applier took (``/metrics``; ``apply_cpu.py`` measures that step alone
by batch size); then the median over the windows. The server is stopped with
SIGTERM and the store must hold every acknowledged notification once.

``--profile`` also samples every process of the server with py-spy (the
``[bench]`` extra) during one extra window and prints where each spends
its samples (``profile_ingest.top_frames``). ``--tree DIR`` runs the server
from another checkout (``DIR/tsdb_service``), for a before/after table on
the same load: ``git worktree add /tmp/before <commit>``. ``--json FILE``
keeps every figure.
"""

from __future__ import annotations

import argparse
import os
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import threading
import time
import urllib.request
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import common
import compare
import wrkrun
from loads import ingest_load

SAMPLES_PER_NOTIFICATION = 6  # TimeInstant and the five attributes of lawnmower.ENTITY_FMT


def _children_cpu() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def process_cpu(server: common.Server) -> dict[str, float]:
    """CPU seconds so far of each process of the server, by role: ``serve``
    (the process started), then its children in order of their pids."""
    procs = server.processes()
    out: dict[str, float] = {}
    for i, p in enumerate(procs):
        try:
            times = p.cpu_times()
            name = "serve" if i == 0 else _role(p)
        except common.psutil.Error:
            continue
        key = name
        n = 2
        while key in out:
            key, n = f"{name}#{n}", n + 1
        out[key] = times.user + times.system
    return out


def loop_cpu(server: common.Server) -> float:
    """CPU seconds so far of the serving process's main thread, where its
    event loop runs (HTTP, parsing, answering): the figure least moved by how
    busy the machine is, since the applier's batches (smaller when the
    machine is busy) are on other threads."""
    procs = server.processes()
    try:
        for thread in procs[0].threads() if procs else ():
            if thread.id == procs[0].pid:
                return thread.user_time + thread.system_time
    except common.psutil.Error:
        pass
    return 0.0


def _role(p) -> str:
    """A child's role: the uvicorn workers of ``--workers N`` (PostgreSQL)."""
    return "worker" if "multiprocessing" in " ".join(p.cmdline()) else "child"


def applied(url: str) -> tuple[float, float, float]:
    """(transactions, samples) the ingest log applied so far, and the writes
    acceptor processes relayed (``--ingest-processes``), from ``/metrics``
    (DuckDB; zeros elsewhere)."""
    found = {
        "tsdb_ingest_log_applied_batches_total": 0.0,
        "tsdb_ingest_log_applied_samples_total": 0.0,
        "tsdb_ingest_relayed_writes_total": 0.0,
    }
    try:
        with urllib.request.urlopen(url + "/metrics", timeout=10) as answer:
            text = answer.read().decode()
    except OSError:
        return 0.0, 0.0, 0.0
    for line in text.splitlines():
        name, _, value = line.partition(" ")
        if name in found:
            found[name] = float(value)
    return (
        found["tsdb_ingest_log_applied_batches_total"],
        found["tsdb_ingest_log_applied_samples_total"],
        found["tsdb_ingest_relayed_writes_total"],
    )


def one_window(server: common.Server, cluster, make, connections: int, seconds: float) -> dict:
    applied0 = applied(server.url)
    loop0 = loop_cpu(server)
    cpu0, db0, wrk0 = process_cpu(server), cluster.cpu_seconds() if cluster else 0.0, _children_cpu()
    script, _ = make(f"c{connections}-{time.monotonic_ns() % 10**6}")
    stats = wrkrun.run(server.url, script, connections, seconds)
    cpu1, db1, wrk1 = process_cpu(server), cluster.cpu_seconds() if cluster else 0.0, _children_cpu()
    loop1 = loop_cpu(server)
    applied1 = applied(server.url)
    ok = max(stats.ok, 1)
    per = {k: (cpu1[k] - cpu0.get(k, 0.0)) * 1000 / ok for k in cpu1}
    row = {
        "connections": connections,
        "ok": stats.ok,
        "rps": round(stats.rps),
        "p99_ms": round(stats.p99_ms, 1),
        "errors": stats.errors + stats.non_2xx,
        "ms_per_notification": {k: round(v, 4) for k, v in per.items()},
        "server_ms": round(sum(per.values()), 4),
        "loop_ms": round((loop1 - loop0) * 1000 / ok, 4),
        "wrk_ms": round((wrk1 - wrk0) * 1000 / ok, 4),
    }
    if cluster:
        row["database_ms"] = round((db1 - db0) * 1000 / ok, 4)
    row["total_ms"] = round(row["server_ms"] + row.get("database_ms", 0.0), 4)
    row["us_per_sample"] = round(row["total_ms"] * 1000 / SAMPLES_PER_NOTIFICATION, 1)
    batches = applied1[0] - applied0[0]
    row["samples_per_apply"] = round((applied1[1] - applied0[1]) / batches) if batches else None
    row["relayed_share"] = round((applied1[2] - applied0[2]) / ok, 3)
    return row


def profile_window(
    server: common.Server, make, connections: int, seconds: float, top: int, gil_only: bool = False
) -> dict:
    """py-spy over every process of the server during one window: each
    process's share of the samples, and its heaviest frames; ``gil_only``:
    only the samples of the thread holding the interpreter lock (what one
    process cannot run in parallel)."""
    import profile_ingest

    pyspy = shutil.which("py-spy") or str(Path(sys.executable).parent / "py-spy")
    script, _ = make(f"p{connections}")
    load = threading.Thread(target=wrkrun.run, args=(server.url, script, connections, seconds + 2))
    load.start()
    time.sleep(1)
    outputs, spies = {}, []
    for i, p in enumerate(server.processes()):
        raw = Path(tempfile.mkstemp(suffix=".raw")[1])
        role = "serve" if i == 0 else f"{_role(p)}-{p.pid}"
        cmd = [pyspy, "record", "--pid", str(p.pid), "--duration", str(int(seconds)), "--format", "raw"]
        cmd += ["--threads", "--output", str(raw), "--rate", "200", "--nonblocking"]
        if gil_only:
            cmd.append("--gil")
        spies.append(subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
        outputs[role] = raw
    for spy in spies:
        spy.wait()
    load.join()
    found = {}
    for role, raw in outputs.items():
        if raw.stat().st_size:
            found[role] = profile_ingest.top_frames(raw, top)
        raw.unlink(missing_ok=True)
    return found


def print_profile(found: dict) -> None:
    grand = sum(t["total"] for t in found.values()) or 1
    for role, top in found.items():
        total = top["total"] or 1
        print(f"\n  py-spy, {role}: {100 * top['total'] / grand:.0f}% of all samples")
        print("    threads: " + ", ".join(f"{k} {v / total:.0%}" for k, v in top["threads"].items()))
        for (kind, frame), c in top["self"]:
            print(f"    {100 * c / total:5.1f}% self  [{kind}] {frame}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--backend", choices=("duckdb", "postgresql"), default="duckdb")
    ap.add_argument("--connections", default="16,64", help="comma list")
    ap.add_argument("--seconds", type=float, default=6.0, help="seconds per measured window")
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--warmup", type=float, default=4.0)
    ap.add_argument("--serve-arg", action="append", default=[], help="an argument for serve (repeatable)")
    ap.add_argument("--server-env", action="append", default=[], metavar="KEY=VALUE")
    ap.add_argument("--tree", type=Path, help="run the server from this checkout (its tsdb_service package)")
    ap.add_argument("--label", default="", help="a name for this configuration in the output")
    ap.add_argument("--profile", action="store_true", help="also a py-spy window per connection count")
    ap.add_argument("--top", type=int, default=12)
    ap.add_argument("--gil", action="store_true", help="--profile: only the thread holding the interpreter lock")
    ap.add_argument("--json", type=Path)
    args = ap.parse_args(argv)
    if wrkrun.ensure_wrk() is None:
        print("wrk is needed (apt-get install wrk)", file=sys.stderr)
        return 2
    workdir = Path(tempfile.mkdtemp(prefix="tsdb-ingest-cpu-"))
    env = dict(item.split("=", 1) for item in args.server_env)
    if args.tree is not None:
        env["PYTHONPATH"] = str(args.tree.resolve())
        # ``python -m`` puts the working directory ahead of PYTHONPATH: run
        # from a checkout, the server would import that checkout instead.
        env["PYTHONSAFEPATH"] = "1"
    cluster = None
    rows: list[dict] = []
    profiles: dict = {}
    try:
        db, cluster = common.fresh_database(args.backend, "ingestcpu", workdir)
        port = common.free_port()
        cmd = common.ours_cmd(db, port) + args.serve_arg
        if args.tree is not None:  # python -m would put the working directory (this checkout) first
            cmd.insert(1, "-P")
        server = common.spawned("ours", cmd, port, workdir, env)
        server.start()
        ledger: list[str] = []
        make = ingest_load(server.url, f"{os.getpid() % 10**5}", ledger)
        label = args.label or " ".join(args.serve_arg) or args.backend
        print(
            f"ingest CPU: {label}; {args.backend}; load {common.load_text()}; "
            f"{common.speed_text(common.speed_probe(workdir))}",
            flush=True,
        )
        try:
            wrkrun.run(server.url, make("w")[0], 64, args.warmup)  # every series exists from here on
            for connections in (int(c) for c in args.connections.split(",")):
                for _ in range(args.reps):
                    row = one_window(server, cluster, make, connections, args.seconds)
                    rows.append(row)
                    split = ", ".join(f"{k} {v:.3f}" for k, v in row["ms_per_notification"].items())
                    db_part = f" + database {row['database_ms']:.3f}" if cluster else ""
                    print(
                        f"  {connections:3d} conns: {row['ok']:7,} ok ({row['rps']:,}/s, p99 {row['p99_ms']} ms, "
                        f"{row['errors']} errors); CPU ms per notification: {split}{db_part} = "
                        f"{row['total_ms']:.3f} ({row['us_per_sample']} us per sample); wrk {row['wrk_ms']:.3f}"
                        + (f"; {row['samples_per_apply']:,} samples per apply" if row["samples_per_apply"] else "")
                        + (f"; {row['relayed_share']:.0%} relayed by acceptors" if row["relayed_share"] else ""),
                        flush=True,
                    )
                if args.profile:
                    profiles[connections] = profile_window(server, make, connections, args.seconds, args.top, args.gil)
                    print_profile(profiles[connections])
        finally:
            server.stop()
        if args.backend == "duckdb":
            stored, distinct = compare.stored_notifications(db, ledger)
            print(f"  stored {stored:,} notifications ({distinct:,} distinct)", flush=True)
    finally:
        if cluster is not None:
            cluster.stop()
        shutil.rmtree(workdir, ignore_errors=True)
    print(f"\n{label}: median over {args.reps} windows, CPU ms per notification (us per stored sample)")
    header = ["connections", "notifications/s", "per process", "in all", "us per sample", "event loop thread"]
    table = []
    for connections in sorted({r["connections"] for r in rows}):
        mine = [r for r in rows if r["connections"] == connections]
        roles = sorted({k for r in mine for k in r["ms_per_notification"]})
        split = ", ".join(
            f"{k} {statistics.median(r['ms_per_notification'].get(k, 0.0) for r in mine):.3f}" for k in roles
        )
        if cluster:
            split += f", database {statistics.median(r['database_ms'] for r in mine):.3f}"
        table.append(
            [
                connections,
                f"{statistics.median(r['rps'] for r in mine):,.0f}",
                split,
                f"{statistics.median(r['total_ms'] for r in mine):.3f}",
                f"{statistics.median(r['us_per_sample'] for r in mine):.1f}",
                f"{statistics.median(r['loop_ms'] for r in mine):.3f}",
            ]
        )
    common.print_rows(header, table)
    if args.json:
        common.write_json(args.json, {"label": label, "args": vars(args), "rows": rows, "profiles": profiles})
    return 0


if __name__ == "__main__":
    sys.exit(main())
