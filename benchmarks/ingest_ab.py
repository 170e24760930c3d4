"""Ingest A/B: our DuckDB server under several environments, runs alternated.

    .venv/bin/python benchmarks/ingest_ab.py base TSDB_WAL_CHECKPOINT_BYTES=16777216
    .venv/bin/python benchmarks/ingest_ab.py --connections 16 --rounds 5 base TSDB_WRITER_THREADS=2
    .venv/bin/python benchmarks/ingest_ab.py --copy-db /tmp/big.duckdb base TSDB_WAL_CHECKPOINT_BYTES=16777216
    .venv/bin/python benchmarks/ingest_ab.py --backend postgresql --workers 2 base TSDB_WRITER_THREADS=1

Each variant is ``base`` (the defaults) or ``KEY=VALUE[,KEY=VALUE...]``
added to the server's environment. A round starts one fresh server per
variant, in turn (a new DuckDB file, or a copy of ``--copy-db`` to measure
a big database), drives ``compare.py``'s ingest load (unique Lawnmower
notifications through wrk, or ``loadgen.py`` without it) for a short
warm-up and then ``--duration`` seconds, and stops it. Alternating the
variants inside each round spreads the machine's drift over all of them;
the table gives each variant's median over the rounds, then every run.

Not a test and not a verdict on issue 15's targets (``compare.py`` is):
this answers "does this setting change the ingest rate, p50, p99 or the
server's CPU per notification" before a default changes.
"""

from __future__ import annotations

import argparse
import contextlib
import shutil
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import common
import loads
import wrkrun


def variant_env(spec: str) -> dict[str, str]:
    """``base`` is the defaults; else ``KEY=VALUE`` pairs separated by commas."""
    if spec == "base":
        return {}
    pairs = [item.split("=", 1) for item in spec.split(",")]
    if any(len(pair) != 2 for pair in pairs):
        raise SystemExit(f"a variant is 'base' or KEY=VALUE[,KEY=VALUE...]: {spec!r}")
    return dict(pairs)


def one_run(
    spec: str,
    tag: str,
    connections: int,
    duration: float,
    warmup: float,
    copy_db: str | None,
    cluster=None,
    workers: int = 1,
) -> dict:
    """One fresh server on a new DuckDB file, or a new database of ``cluster``."""
    work = Path(tempfile.mkdtemp(prefix="ingest-ab-"))
    db: Path | str = work / "db.duckdb"
    if cluster is not None:
        db = cluster.cluster.database(f"ab{tag}_{abs(hash(spec)) % 10**6}")
    elif copy_db:
        shutil.copy(copy_db, db)
    port = common.free_port()
    server = common.spawned("ab", common.ours_cmd(db, port, workers), port, work, variant_env(spec)).start()
    try:
        make = loads.ingest_load(server.url, f"ab{tag}", [])
        if warmup > 0:
            wrkrun.run(server.url, make("w")[0], connections, warmup)
        cpu0 = server.cpu_seconds()
        stats = wrkrun.run(server.url, make("1")[0], connections, duration).to_dict()
        cpu = server.cpu_seconds() - cpu0
    finally:
        server.stop()
        shutil.rmtree(work, ignore_errors=True)
    if stats["non_2xx"] or stats["errors"]:
        raise SystemExit(f"{spec}: {stats['non_2xx']} non-2xx answers and {stats['errors']} errors")
    return {
        "rps": stats["rps"],
        "p50_ms": stats["p50_ms"],
        "p99_ms": stats["p99_ms"],
        "cpu_ms_per_notification": cpu / max(1, stats["requests"]) * 1000,
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("variants", nargs="+", help="'base' or KEY=VALUE[,KEY=VALUE...] per variant")
    parser.add_argument("--connections", type=int, default=64)
    parser.add_argument("--duration", type=float, default=8.0)
    parser.add_argument("--warmup", type=float, default=2.0)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--copy-db", help="start every run from a copy of this DuckDB file")
    parser.add_argument("--backend", choices=["duckdb", "postgresql"], default="duckdb")
    parser.add_argument("--workers", type=int, default=1, help="server processes (PostgreSQL only)")
    parser.add_argument("--json", help="write every run here")
    args = parser.parse_args(argv)
    if wrkrun.ensure_wrk() is None:
        raise SystemExit("wrk is needed (apt-get install wrk)")
    runs: dict[str, list[dict]] = {spec: [] for spec in args.variants}
    with contextlib.ExitStack() as stack:
        cluster = None
        if args.backend == "postgresql":
            from pgutil import BenchCluster

            cluster = stack.enter_context(BenchCluster())
        _rounds(args, runs, cluster)
    _report(args, runs)
    return 0


def _rounds(args, runs: dict[str, list[dict]], cluster) -> None:
    for r in range(args.rounds):
        for spec in args.variants:
            got = one_run(
                spec, f"{r}", args.connections, args.duration, args.warmup, args.copy_db, cluster, args.workers
            )
            runs[spec].append(got)
            print(
                f"round {r + 1}  {spec:40s} {got['rps']:8,.0f}/s  p50 {got['p50_ms']:6.1f}  "
                f"p99 {got['p99_ms']:6.1f} ms  CPU {got['cpu_ms_per_notification']:.3f} ms/notification  "
                f"(load {common.load_text(common.loadavg(1))})",
                flush=True,
            )


def _report(args, runs: dict[str, list[dict]]) -> None:
    rounds = f"{args.rounds} round{'s' if args.rounds != 1 else ''}"
    print(f"\n{args.connections} connections, {rounds} of {args.duration:g} s; medians [min-max]:")
    for spec, got in runs.items():
        cells = [
            common.spread_text([g[key] for g in got], digits=digits, thousands=key == "rps")
            for key, digits in (("rps", 0), ("p50_ms", 1), ("p99_ms", 1), ("cpu_ms_per_notification", 3))
        ]
        print(f"  {spec:40s} rate {cells[0]}/s  p50 {cells[1]} ms  p99 {cells[2]} ms  CPU {cells[3]} ms/notification")
    if args.json:
        common.write_json(args.json, {"connections": args.connections, "copy_db": args.copy_db, "runs": runs})


if __name__ == "__main__":
    raise SystemExit(main())
