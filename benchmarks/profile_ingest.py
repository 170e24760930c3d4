"""Profile our ingest under wrk load with py-spy: the flame graph's top items.

    .venv/bin/python benchmarks/profile_ingest.py --backend duckdb --connections 16 [--seconds 10]

Starts tsdb-service (DuckDB file, or a private PostgreSQL cluster), drives it
with compare.py's Lawnmower notifications through wrk, samples every thread
with ``py-spy record --format raw`` (collapsed stacks; ``--svg`` also writes
the flame graph) and prints the frames with the most samples: self time (the
frame on top of the stack) and inclusive time (anywhere in the stack), per
thread kind (event loop, writer, other). py-spy is in the ``[bench]`` extra;
it needs ptrace rights over the server (root, or the same user with
``kernel.yama.ptrace_scope=0``).
"""

from __future__ import annotations

import argparse
import collections
import re
import shutil
import subprocess
import sys
import tempfile
import threading
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import common
import compare
import lawnmower
import wrkrun


def top_frames(raw: Path, n: int) -> dict:
    """Self and inclusive sample counts per frame from py-spy's collapsed stacks."""
    selfc: collections.Counter = collections.Counter()
    incl: collections.Counter = collections.Counter()
    threads: collections.Counter = collections.Counter()
    total = 0
    for line in raw.read_text().splitlines():
        stack, _, count = line.rpartition(" ")
        if not stack:
            continue
        c = int(count)
        frames = stack.split(";")
        thread = frames[0]
        kind = (
            "writer"
            if "writer" in thread
            else ("event loop" if "MainThread" in thread or "uvicorn" in thread else "other")
        )
        threads[kind] += c
        total += c
        frames = [_short(f) for f in frames[1:]]
        if frames:
            selfc[(kind, frames[-1])] += c
        for f in set(frames):
            incl[(kind, f)] += c
    return {"total": total, "threads": threads, "self": selfc.most_common(n), "inclusive": incl.most_common(n)}


def _short(frame: str) -> str:
    # "func (path/to/module.py:123)" -> "func (module.py:123)"
    return re.sub(r"\(([^()]*/)?([^/()]+)\)$", r"(\2)", frame)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--backend", choices=("duckdb", "postgresql"), default="duckdb")
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--connections", type=int, default=16)
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--top", type=int, default=15)
    ap.add_argument("--svg", type=Path, help="also write the flame graph here")
    args = ap.parse_args(argv)
    pyspy = shutil.which("py-spy") or str(Path(sys.executable).parent / "py-spy")
    workdir = Path(tempfile.mkdtemp(prefix="tsdb-profile-"))
    cluster = None
    try:
        db, cluster = common.fresh_database(args.backend, "profile", workdir)
        port = common.free_port()
        server = common.spawned("ours", common.ours_cmd(db, port, args.workers), port, workdir)
        server.start()
        try:
            prelude, expr = lawnmower.ingest_lua("prof", compare.POOL)
            script = wrkrun.post_script("/v2/notify", lawnmower.headers(lawnmower.INGEST_TENANT), prelude, expr, 2)
            wrkrun.run(server.url, script, args.connections, 2)  # warm-up
            result: dict = {}
            load = threading.Thread(
                target=lambda: result.update(
                    wrkrun.run(server.url, script, args.connections, args.seconds + 2).to_dict()
                )
            )
            load.start()
            raw = workdir / "profile.raw"
            cmd = [
                pyspy,
                "record",
                "--pid",
                str(server.proc.pid),
                "--duration",
                str(int(args.seconds)),
                "--format",
                "raw",
                "--threads",
                "--output",
                str(raw),
                "--rate",
                "200",
                "--nonblocking",
            ]
            if args.workers > 1:
                cmd.append("--subprocesses")
            subprocess.run(cmd, check=True, capture_output=True)
            if args.svg:
                subprocess.run(
                    [
                        pyspy,
                        "record",
                        "--pid",
                        str(server.proc.pid),
                        "--duration",
                        "3",
                        "--threads",
                        "--output",
                        str(args.svg),
                        "--nonblocking",
                    ],
                    check=False,
                    capture_output=True,
                )
            load.join()
        finally:
            server.stop()
        top = top_frames(raw, args.top)
    finally:
        if cluster is not None:
            cluster.stop()
    print(
        f"ingest profile: {args.backend}, {args.workers} worker(s), {args.connections} connections; "
        f"wrk: {result.get('rps', 0):,.0f}/s p50 {result.get('p50_ms', 0):.1f} ms p99 {result.get('p99_ms', 0):.1f} ms"
    )
    total = top["total"] or 1
    print("samples per thread kind: " + ", ".join(f"{k} {v / total:.0%}" for k, v in top["threads"].items()))
    for what in ("self", "inclusive"):
        print(f"\ntop {what} (% of all samples):")
        for (kind, frame), c in top[what]:
            print(f"  {100 * c / total:5.1f}%  [{kind}] {frame}")
    shutil.rmtree(workdir, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
