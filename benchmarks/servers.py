"""HTTP servers side by side: uvicorn against granian, and the raw ASGI ceiling.

    .venv/bin/python benchmarks/servers.py                 # ~4 min: every target, 2 reps
    .venv/bin/python benchmarks/servers.py --reps 3 --duration 8

Issue 30 asks which server to keep. Each target gets the ingest load of
``compare.py`` (unique Lawnmower notifications) at 16 and 64 connections and
a lastN=100 GET at 8 connections:

* the bare FastAPI app (``bare_app:app``) under uvicorn and under granian;
* the raw ASGI app (``bare_app:raw_app``: no framework) under both: the
  ceiling a route served ahead of the framework can approach;
* ours on a fresh DuckDB file under both (``tsdb_service.app:create_app_from_env``).

Ours under granian runs without ``serve``'s own HTTP defences (slow
clients, head sizes: ``http.server``), which are uvicorn protocol classes:
the figure says what the server alone would change. Targets run one after
the other; the load average before each is printed, and the JSON has every
run. Only ratios measured in one run count on this shared machine.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import common
import lawnmower
from common import HERE, free_port, granian_cmd, raw_cmd, spawned
from loads import Runner, get_load, ingest_load, summary

LASTN = "/v2/entities/urn:ngsi-ld:Lawnmower:q00/attrs/batteryLevel?lastN=100"


def targets(workdir: Path) -> list[tuple[str, list[str], dict[str, str]]]:
    """(name, command, environment) for every target, built on free ports."""
    db_u, db_g = workdir / "uvicorn.duckdb", workdir / "granian.duckdb"
    out = []
    out.append(("bare FastAPI, uvicorn", common.bare_cmd, {}))
    out.append(("bare FastAPI, granian", lambda port: granian_cmd("bare_app:app", port, app_dir=HERE), {}))
    out.append(("raw ASGI, uvicorn", raw_cmd, {}))
    out.append(("raw ASGI, granian", lambda port: granian_cmd("bare_app:raw_app", port, app_dir=HERE), {}))
    out.append(("ours DuckDB, uvicorn", lambda port: common.ours_cmd(db_u, port), {}))
    out.append(
        (
            "ours DuckDB, granian",
            lambda port: granian_cmd("tsdb_service.app:create_app_from_env", port, factory=True),
            {"TSDB_DB": str(db_g)},
        )
    )
    return out  # type: ignore[return-value]


def measure(name: str, make_cmd, env: dict[str, str], runner: Runner, workdir: Path) -> dict:
    port = free_port()
    server = spawned(name.replace(" ", "_").replace(",", ""), make_cmd(port), port, workdir, env)
    server.start()
    print(f"- {name} on :{port} (load {common.load_text()})", flush=True)
    runs: dict[str, list[dict]] = {}
    try:
        for conns in (16, 64):
            ledger: list[str] = []
            runs[f"ingest{conns}"] = runner.repeat(
                server.url, ingest_load(server.url, f"s{port}{conns}", ledger), conns
            )
        if name.startswith("ours"):
            lawnmower.load_dataset(server.url)
        runs["lastN8"] = runner.repeat(server.url, get_load(server.url, [LASTN], lawnmower.query_headers()), 8)
        cpu = server.cpu_seconds()
    finally:
        server.stop()
    figures = {key: summary(value, "rps") for key, value in runs.items()}
    p99 = {key: summary(value, "p99_ms") for key, value in runs.items()}
    for key in runs:
        print(f"    {key:9} {figures[key]['median']:9,.0f}/s  p99 {p99[key]['median']:7.1f} ms", flush=True)
    return {"name": name, "runs": runs, "cpu_s": cpu}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--reps", type=int, default=2)
    ap.add_argument("--duration", type=float, default=6.0)
    ap.add_argument("--warmup", type=float, default=2.0)
    ap.add_argument("--only", help="comma list of target names' first words (bare, raw, ours)")
    ap.add_argument("--json", type=Path)
    args = ap.parse_args(argv)
    runner = Runner(use_wrk=common_wrk(), reps=args.reps, duration=args.duration, warmup=args.warmup)
    results = []
    with tempfile.TemporaryDirectory(prefix="servers-") as tmp:
        workdir = Path(tmp)
        for name, make_cmd, env in targets(workdir):
            if args.only and name.split()[0].lower() not in args.only.split(","):
                continue
            results.append(measure(name, make_cmd, env, runner, workdir))
    print("\nmedians, req/s (p99 ms):")
    for r in results:
        cells = []
        for key in ("ingest16", "ingest64", "lastN8"):
            rps, p99 = summary(r["runs"][key], "rps"), summary(r["runs"][key], "p99_ms")
            cells.append(f"{key} {rps['median']:8,.0f} ({p99['median']:.1f})")
        print(f"  {r['name']:24} " + "   ".join(cells))
    if args.json:
        args.json.write_text(json.dumps(results, indent=2, default=str))
    return 0


def common_wrk() -> bool:
    import shutil

    return shutil.which("wrk") is not None


if __name__ == "__main__":
    sys.exit(main())
