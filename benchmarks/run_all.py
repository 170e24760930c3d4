"""Every benchmark, on every backend, in one command, with one table.

    .venv/bin/python benchmarks/run_all.py                 # full set, DuckDB and PostgreSQL
    .venv/bin/python benchmarks/run_all.py --quick         # smoke run, under 3 minutes
    .venv/bin/python benchmarks/run_all.py --backends duckdb

For each backend it runs, one after the other (never two loads at once: the
machine has two cores), each as a subprocess writing ``--json``:

* ``benchmarks/ingest.py --backend B`` (our server, then the bare FastAPI
  ceiling); on PostgreSQL also ``--workers 2`` (our server only);
* ``benchmarks/queries.py --backend B`` (full: 10M samples; ``--quick``:
  ``--scale 0.1``, i.e. 1M samples -- the table says so);
* ``benchmarks/geo.py`` when it exists and takes ``--json`` (and
  ``--backend`` for PostgreSQL); otherwise a note says why it was skipped.
  Not in ``--quick`` (its load alone takes ~1.5 min) unless ``--only geo``.

Then it prints one table -- benchmark | metric | DuckDB | PostgreSQL | target
| pass/fail -- and writes everything (each benchmark's
JSON, the table, the load averages before and after each step) to
``benchmarks/results/latest.json``. Each step's output goes to
``benchmarks/results/logs/``.

It keeps no QuantumLeap figure: ratios to QuantumLeap come only from
``compare.py --url ql=URL``, which measures a running QuantumLeap in the same
run.

Exit status: 0 when every step ran and produced its JSON (targets may still
FAIL: they are in the table); 1 when a step crashed; with ``--strict``, also
1 when a target fails.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import subprocess
import sys
import time
from datetime import UTC, datetime
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import common
from common import HERE, ROOT, loadavg

RESULTS = HERE / "results"
LOGS = RESULTS / "logs"
BACKENDS = ("duckdb", "postgresql")
LABEL = {"duckdb": "DuckDB", "postgresql": "PostgreSQL"}


def geo_capabilities(python: str) -> dict:
    """What ``geo.py --help`` offers, or why it cannot be run."""
    script = HERE / "geo.py"
    if not script.exists():
        return {"usable": False, "why": "benchmarks/geo.py does not exist (yet)"}
    try:
        out = subprocess.run([python, str(script), "--help"], capture_output=True, text=True, timeout=60, cwd=ROOT)
    except subprocess.TimeoutExpired:
        return {"usable": False, "why": "geo.py --help did not answer within 60 s"}
    text = out.stdout + out.stderr
    if out.returncode != 0:
        return {"usable": False, "why": f"geo.py --help exited {out.returncode}: {text.strip()[-300:]}"}
    caps = {
        flag: flag in text
        for flag in ("--json", "--backend", "--scale", "--duration", "--warmup", "--quick", "--entities")
    }
    if not caps["--json"]:
        return {"usable": False, "why": "geo.py has no --json option", **caps}
    return {"usable": True, **caps}


class Step:
    def __init__(self, key: str, backend: str, cmd: list[str], json_path: Path, timeout: float, log_dir: Path = LOGS):
        self.key, self.backend, self.cmd, self.json_path, self.timeout = key, backend, cmd, json_path, timeout
        self.log_path = log_dir / f"{key}-{backend}.log"
        self.result: dict | None = None
        self.rc: int | None = None
        self.error: str | None = None
        self.seconds = 0.0
        self.load_before: list[float] = []
        self.load_after: list[float] = []

    def run(self) -> None:
        self.json_path.unlink(missing_ok=True)
        self.load_before = loadavg()
        print(
            f"[{datetime.now().strftime('%H:%M:%S')}] {self.key} on {LABEL[self.backend]} "
            f"(load avg {' '.join(map(str, self.load_before))}) ... ",
            end="",
            flush=True,
        )
        t0 = time.monotonic()
        with open(self.log_path, "w") as log:
            log.write("$ " + " ".join(self.cmd) + "\n\n")
            log.flush()
            try:
                proc = subprocess.Popen(
                    self.cmd,
                    stdout=log,
                    stderr=subprocess.STDOUT,
                    cwd=ROOT,
                    stdin=subprocess.DEVNULL,
                    start_new_session=True,
                )
                try:
                    self.rc = proc.wait(self.timeout)
                except subprocess.TimeoutExpired:
                    # the benchmark's own process group: its servers and clusters are its children
                    os.killpg(proc.pid, 15)
                    try:
                        proc.wait(60)
                    except subprocess.TimeoutExpired:
                        os.killpg(proc.pid, 9)
                        proc.wait()
                    self.error = f"timed out after {self.timeout:.0f} s"
            except OSError as exc:
                self.error = str(exc)
        self.seconds = time.monotonic() - t0
        self.load_after = loadavg()
        if self.json_path.exists():
            try:
                self.result = json.loads(self.json_path.read_text())
            except ValueError as exc:
                self.error = self.error or f"unreadable JSON: {exc}"
        elif not self.error:
            self.error = f"exit code {self.rc}, no JSON written"
        status = (
            f"error: {self.error}"
            if self.error
            else f"done (exit {self.rc}: {'all targets pass' if self.rc == 0 else 'some target fails'})"
        )
        print(f"{status}, {self.seconds:.0f} s, log {self.log_path.relative_to(ROOT)}", flush=True)

    def to_dict(self) -> dict:
        return {
            "cmd": self.cmd,
            "exit_code": self.rc,
            "error": self.error,
            "seconds": round(self.seconds, 1),
            "loadavg_before": self.load_before,
            "loadavg_after": self.load_after,
            "log": str(self.log_path),
            "result": self.result,
        }


# --------------------------------------------------------------------------
# the table


def num(v, digits: int = 0, unit: str = "") -> str:
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "-"
    return f"{v:,.{digits}f}{unit}"


class Row:
    """One metric, one cell per backend; pass/fail per backend when there is a target."""

    def __init__(
        self,
        bench: str,
        metric: str,
        target: str = "",
        check=None,
        digits: int = 0,
    ):
        self.bench, self.metric, self.target, self.check = bench, metric, target, check
        self.digits = digits
        self.values: dict[str, object] = {}
        self.texts: dict[str, str] = {}

    def set(self, backend: str, value, text: str | None = None) -> None:
        self.values[backend] = value
        self.texts[backend] = text if text is not None else num(value, self.digits)

    def verdict(self, backend: str) -> bool | None:
        if self.check is None or backend not in self.values or self.values[backend] is None:
            return None
        return bool(self.check(self.values[backend]))


def dig(d: dict | None, *path, default=None):
    for p in path:
        if not isinstance(d, dict) or p not in d:
            return default
        d = d[p]
    return d


def build_rows(steps: dict[tuple[str, str], Step], backends: list[str]) -> tuple[list[Row], list[str]]:
    notes: list[str] = []
    rows: list[Row] = []

    def add(row: Row, getter) -> None:
        for b in backends:
            value = getter(b)
            if isinstance(value, tuple):
                row.set(b, *value)
            elif value is not None:
                row.set(b, value)
        if row.values:
            rows.append(row)

    def result(key: str, backend: str) -> dict | None:
        step = steps.get((key, backend))
        return step.result if step is not None else None

    ing = lambda b: result("ingest", b)  # noqa: E731
    ing2 = lambda b: result("ingest-2workers", b)  # noqa: E731
    qry = lambda b: result("queries", b)  # noqa: E731
    geo = lambda b: result("geo", b)  # noqa: E731

    # ingest ------------------------------------------------------------------------------
    add(
        Row(
            "ingest",
            "notif/s, 1 server process",
            ">= 5,000",
            lambda v: v >= 5000,
        ),
        lambda b: dig(ing(b), "targets", "ours", "load", "rps"),
    )
    add(
        Row("ingest", "notif/s, 2 workers"),
        lambda b: dig(ing2(b), "targets", "ours", "load", "rps") if b == "postgresql" else None,
    )
    add(
        Row("ingest", "bare FastAPI ceiling, notif/s"),
        lambda b: dig(ing(b), "targets", "bare", "load", "rps"),
    )
    add(Row("ingest", "ratio ours / bare", ">= 0.60", lambda v: v >= 0.6, digits=2), lambda b: dig(ing(b), "ratio"))
    add(Row("ingest", "p50 latency ms", "", digits=1), lambda b: dig(ing(b), "targets", "ours", "load", "p50_ms"))
    add(
        Row("ingest", "p99 latency ms", "<= 50", lambda v: v <= 50, digits=1),
        lambda b: dig(ing(b), "targets", "ours", "load", "p99_ms"),
    )
    add(
        Row("ingest", "p99 latency ms, 2 workers", "", digits=1),
        lambda b: dig(ing2(b), "targets", "ours", "load", "p99_ms") if b == "postgresql" else None,
    )

    def errors(b):
        s = dig(ing(b), "targets", "ours", "load")
        return None if s is None else s["non_2xx"] + s["errors"]

    add(Row("ingest", "non-2xx + errors", "= 0", lambda v: v == 0), errors)

    def lost(b, get=ing):
        v = dig(get(b), "targets", "ours", "verification")
        if v is None:
            return None
        return (
            v["lost"] if v["ok"] else max(v["lost"], 1),
            f"{v['lost']:,} of {v['acknowledged']:,}" + ("" if v["ok"] else " (check failed)"),
        )

    add(Row("ingest", "acknowledged but not stored", "= 0", lambda v: v == 0), lost)
    add(
        Row("ingest", "  same, 2 workers", "= 0", lambda v: v == 0),
        lambda b: lost(b, ing2) if b == "postgresql" else None,
    )
    add(
        Row("ingest", "server CPU % (+ PostgreSQL CPU %)"),
        lambda b: (
            (
                dig(ing(b), "targets", "ours", "server_cpu_pct"),
                num(dig(ing(b), "targets", "ours", "server_cpu_pct"))
                + (
                    f" (+{num(dig(ing(b), 'targets', 'ours', 'db_cpu_pct'))})"
                    if dig(ing(b), "targets", "ours", "db_cpu_pct") is not None
                    else ""
                ),
            )
            if dig(ing(b), "targets", "ours")
            else None
        ),
    )

    # queries -----------------------------------------------------------------------------
    def dataset(b):
        q = qry(b)
        if q is None:
            return None
        samples = q.get("samples") or dig(q, "load", "samples")
        scale = q.get("scale", 1.0)
        text = f"{samples / 1e6:g}M samples" + ("" if scale == 1.0 else f" (SCALE {scale:g})")
        return samples, text

    add(Row("queries", "data set loaded (target: 10M)", "10M", lambda v: v >= 10_000_000), dataset)

    def load_rate(b):
        ld = dig(qry(b), "load")
        if not ld or "load_s" not in ld:
            return None
        post = ld.get("compact_s", ld.get("vacuum_analyze_s"))
        return ld["samples"] / ld["load_s"], (
            f"{ld['samples'] / ld['load_s'] / 1000:,.0f}k/s ({ld['load_s']:.0f} s + {post:.0f} s)"
        )

    add(Row("queries", "bulk load samples/s (load + compact/vacuum)"), load_rate)
    add(
        Row("queries", "lastN=100 req/s (8 conns)", ">= 2,000", lambda v: v >= 2000),
        lambda b: dig(qry(b), "results", "lastN", "rps"),
    )
    add(
        Row("queries", "lastN=100 p50 ms", "<= 5", lambda v: v <= 5, digits=2),
        lambda b: dig(qry(b), "results", "lastN", "p50_ms"),
    )
    add(Row("queries", "lastN=100 p99 ms", "", digits=2), lambda b: dig(qry(b), "results", "lastN", "p99_ms"))
    add(
        Row("queries", "lastN=100 p50 ms, 1 conn (unloaded)", "", digits=2),
        lambda b: dig(qry(b), "results", "lastN_1conn", "p50_ms"),
    )
    add(
        Row("queries", "hourly avg over 1 day req/s"),
        lambda b: dig(qry(b), "results", "hourly_avg", "rps"),
    )
    add(
        Row("queries", "hourly avg p50 ms", "<= 20", lambda v: v <= 20, digits=2),
        lambda b: dig(qry(b), "results", "hourly_avg", "p50_ms"),
    )
    add(Row("queries", "types lastN=1000 req/s (2 conns)"), lambda b: dig(qry(b), "results", "type_lastN", "rps"))
    add(Row("queries", "types lastN=1000 p50 ms", digits=1), lambda b: dig(qry(b), "results", "type_lastN", "p50_ms"))

    def query_errors(b):
        res = dig(qry(b), "results")
        return None if res is None else sum(r["errors"] + r["non_2xx"] for r in res.values())

    add(Row("queries", "non-2xx + errors, all scenarios", "= 0", lambda v: v == 0), query_errors)
    add(
        Row("queries", "server RSS MiB"),
        lambda b: (dig(qry(b), "rss_bytes") / 2**20) if dig(qry(b), "rss_bytes") else None,
    )
    add(
        Row("queries", "PostgreSQL server memory MiB (PSS)"),
        lambda b: (dig(qry(b), "db_server_memory_bytes") / 2**20) if dig(qry(b), "db_server_memory_bytes") else None,
    )
    add(Row("queries", "bytes on disk per sample", digits=1), lambda b: dig(qry(b), "bytes_per_sample"))

    # geo (benchmarks/geo.py: scenarios "1conn", "loaded", "baseline") -------------------------
    def geo_get(scenario: str, field: str):
        return lambda b: dig(geo(b), "results", scenario, field)

    def geo_conns(b):
        return dig(geo(b), "results", "loaded", "connections")

    add(
        Row("geo", "near;maxDistance:1000 + lastN=10 p50 ms, 1 conn", "<= 30", lambda v: v <= 30, digits=1),
        geo_get("1conn", "p50_ms"),
    )
    add(
        Row("geo", "same, p50 ms under load (4 conns)", "<= 30", lambda v: v <= 30, digits=1),
        geo_get("loaded", "p50_ms"),
    )
    add(Row("geo", "same, req/s under load (4 conns)", digits=1), geo_get("loaded", "rps"))
    add(Row("geo", "same entities by id, no geo: p50 ms, 1 conn", digits=1), geo_get("baseline", "p50_ms"))

    def geo_errors(b):
        res = dig(geo(b), "results")
        return None if res is None else sum(r["errors"] + r["non_2xx"] for r in res.values())

    add(Row("geo", "non-2xx + errors", "= 0", lambda v: v == 0), geo_errors)
    if any(geo(b) for b in backends):
        g = next(geo(b) for b in backends if geo(b))
        samples = dig(g, "load", "samples")
        notes.append(
            f"geo: 10,000 entities x 100 samples{f' ({samples:,} samples incl. positions)' if samples else ''}"
            f", location in {g.get('location', '?')} sample; "
            f"{dig(g, 'check', 'matched_mean')} entities within 1,000 m on average."
        )

    notes.append("Against QuantumLeap: compare.py --url ql=URL measures a running one in the same run.")
    return rows, notes


def print_table(rows: list[Row], backends: list[str]) -> list[dict]:
    header = [
        "benchmark",
        "metric",
        *[LABEL[b] for b in backends],
        "target",
        "pass/fail (" + "/".join("D" if b == "duckdb" else "P" for b in backends) + ")",
    ]
    table = []
    for r in rows:
        verdicts = [r.verdict(b) for b in backends]
        pf = (
            ""
            if all(v is None for v in verdicts)
            else " / ".join("-" if v is None else ("PASS" if v else "FAIL") for v in verdicts)
        )
        table.append(
            [
                r.bench,
                r.metric,
                *[r.texts.get(b, "n/a") for b in backends],
                r.target,
                pf,
            ]
        )
    widths = [max(len(str(x)) for x in col) for col in zip(header, *table, strict=False)]
    line = "  ".join("-" * w for w in widths)

    def fmt(cells):
        return "  ".join(
            str(c).ljust(w) if i < 2 else str(c).rjust(w) if 2 <= i < 2 + len(backends) else str(c).ljust(w)
            for i, (c, w) in enumerate(zip(cells, widths, strict=False))
        )

    print(fmt(header))
    print(line)
    previous = None
    for cells in table:
        if previous is not None and cells[0] != previous:
            print(line)
        previous = cells[0]
        print(fmt(cells))
    out = []
    for r in rows:
        out.append(
            {
                "benchmark": r.bench,
                "metric": r.metric,
                "target": r.target,
                **{b: {"value": r.values.get(b), "text": r.texts.get(b), "pass": r.verdict(b)} for b in backends},
            }
        )
    return out


# --------------------------------------------------------------------------


def report(path: Path) -> int:
    """Re-print the table of an earlier run from its combined JSON."""
    combined = json.loads(path.read_text())
    backends = combined["backends"]
    steps: dict[tuple[str, str], Step] = {}
    for name, data in combined["steps"].items():
        key, backend = name.split(":")
        step = Step(key, backend, data["cmd"], Path("/dev/null"), 0)
        step.result, step.rc, step.error = data["result"], data["exit_code"], data["error"]
        steps[(key, backend)] = step
    quick = combined.get("quick")
    kind = f"QUICK smoke run, queries at scale {combined['queries_scale']:g}" if quick else "full run"
    print(f"RESULTS of {combined['started_at']} ({kind}; {combined['machine']['cpus']} CPUs)")
    rows, notes = build_rows(steps, backends)
    print_table(rows, backends)
    print()
    for note in notes:
        print(note)
    geo_caps = combined.get("geo") or {}
    if not geo_caps.get("usable", True):
        print(f"geo: skipped -- {geo_caps.get('why')}")
    print(
        f"load average (1/5/15 min): {' '.join(map(str, combined['machine']['loadavg_start']))} at start, "
        f"{' '.join(map(str, combined['machine']['loadavg_end']))} at end"
    )
    for name, data in combined["steps"].items():
        print(
            f"  {name:<28} {data['seconds']:>6.0f} s  load avg before {' '.join(map(str, data['loadavg_before']))}"
            f", after {' '.join(map(str, data['loadavg_after']))}"
        )
    return 0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument(
        "--quick",
        action="store_true",
        help="smoke run: short windows, queries at scale 0.1 (1M samples); under 3 minutes",
    )
    ap.add_argument("--backends", default="duckdb,postgresql", help="comma list of duckdb, postgresql (default both)")
    ap.add_argument(
        "--only",
        help="comma list of ingest, queries, geo (default: all; with --quick: ingest, "
        "queries -- geo.py has no reduced scale, its load alone takes ~1.5 min)",
    )
    ap.add_argument("--no-pg-workers", action="store_true", help="skip the 2-worker ingest run on PostgreSQL")
    ap.add_argument("--scale", type=float, help="queries data-set scale (default 1, or 0.1 with --quick)")
    ap.add_argument("--out", type=Path, default=RESULTS / "latest.json", help="combined JSON (default %(default)s)")
    ap.add_argument("--strict", action="store_true", help="exit 1 when any target fails")
    ap.add_argument(
        "--report",
        type=Path,
        metavar="FILE",
        help="run nothing: print the table of a combined JSON written earlier (e.g. latest.json)",
    )
    args = ap.parse_args(argv)
    if args.report:
        return report(args.report)

    backends = [b.strip() for b in args.backends.split(",") if b.strip()]
    if not backends or set(backends) - set(BACKENDS):
        ap.error("--backends takes duckdb and/or postgresql")
    only_default = args.only is None
    only = {x.strip() for x in (args.only or "ingest,queries,geo").split(",") if x.strip()}
    if only - {"ingest", "queries", "geo"}:
        ap.error("--only takes ingest, queries, geo")
    python = sys.executable
    RESULTS.mkdir(parents=True, exist_ok=True)
    # one log directory per combined output: a --quick run does not overwrite the logs of latest.json
    log_dir = LOGS if args.out.resolve() == (RESULTS / "latest.json").resolve() else LOGS / args.out.stem
    log_dir.mkdir(parents=True, exist_ok=True)

    if args.quick:
        ingest_opts = ["--duration", "3", "--warmup", "1"]
        scale = args.scale or 0.1
        query_opts = ["--duration", "2", "--warmup", "0.5", "--scale", f"{scale:g}"]
        timeout = 300.0
    else:
        ingest_opts = []
        scale = args.scale or 1.0
        query_opts = ["--scale", f"{scale:g}"]
        timeout = 2400.0

    if args.quick and only_default:
        only.discard("geo")
        geo_caps = {
            "usable": False,
            "why": "not part of --quick (geo.py has no reduced scale: loading its 2M rows "
            "alone takes ~1.5 min); run it with --quick --only geo, or without --quick",
        }
    elif "geo" in only:
        geo_caps = geo_capabilities(python)
    else:
        geo_caps = {"usable": False, "why": "not selected (--only)"}
    started = datetime.now(UTC)
    load_start = loadavg()
    print(
        f"benchmarks: {', '.join(LABEL[b] for b in backends)}; {'QUICK smoke run' if args.quick else 'full run'}; "
        f"{os.cpu_count()} CPUs; load average {' '.join(map(str, load_start))} (1/5/15 min)",
        flush=True,
    )
    if not geo_caps["usable"]:
        print(f"note: geo benchmark skipped: {geo_caps['why']}", flush=True)

    steps: dict[tuple[str, str], Step] = {}
    for b in backends:
        if "ingest" in only:
            steps[("ingest", b)] = Step(
                "ingest",
                b,
                [
                    python,
                    str(HERE / "ingest.py"),
                    "--backend",
                    b,
                    *ingest_opts,
                    "--json",
                    str(RESULTS / f"ingest-{b}.json"),
                ],
                RESULTS / f"ingest-{b}.json",
                timeout,
                log_dir,
            )
            if b == "postgresql" and not args.no_pg_workers:
                steps[("ingest-2workers", b)] = Step(
                    "ingest-2workers",
                    b,
                    [
                        python,
                        str(HERE / "ingest.py"),
                        "--backend",
                        b,
                        "--workers",
                        "2",
                        "--targets",
                        "ours",
                        *ingest_opts,
                        "--json",
                        str(RESULTS / f"ingest-2workers-{b}.json"),
                    ],
                    RESULTS / f"ingest-2workers-{b}.json",
                    timeout,
                    log_dir,
                )
        if "queries" in only:
            steps[("queries", b)] = Step(
                "queries",
                b,
                [
                    python,
                    str(HERE / "queries.py"),
                    "--backend",
                    b,
                    *query_opts,
                    "--json",
                    str(RESULTS / f"queries-{b}.json"),
                ],
                RESULTS / f"queries-{b}.json",
                timeout,
                log_dir,
            )
        if geo_caps["usable"]:
            if b != "duckdb" and not geo_caps.get("--backend"):
                print(f"note: geo benchmark not run on {LABEL[b]}: geo.py has no --backend option", flush=True)
            else:
                cmd = [python, str(HERE / "geo.py"), "--json", str(RESULTS / f"geo-{b}.json")]
                if geo_caps.get("--backend"):
                    cmd += ["--backend", b]
                if args.quick:
                    if geo_caps.get("--quick"):
                        cmd += ["--quick"]
                    else:
                        if geo_caps.get("--duration"):
                            cmd += ["--duration", "2"]
                        if geo_caps.get("--warmup"):
                            cmd += ["--warmup", "0.5"]
                steps[("geo", b)] = Step("geo", b, cmd, RESULTS / f"geo-{b}.json", timeout, log_dir)

    for step in steps.values():
        step.run()
    load_end = loadavg()

    print()
    kind = f"QUICK smoke run: short windows, queries at scale {scale:g}" if args.quick else "full run"
    print(f"RESULTS ({kind}; {os.cpu_count()} CPUs, {platform.machine()}; one server process unless stated)")
    rows, notes = build_rows(steps, backends)
    table = print_table(rows, backends)
    print()
    for note in notes:
        print(note)
    if not geo_caps["usable"]:
        print(f"geo: skipped -- {geo_caps['why']}")
    elif any(b != "duckdb" for b in backends) and not geo_caps.get("--backend"):
        print("geo: DuckDB only -- benchmarks/geo.py has no --backend option yet")
    where = args.out.relative_to(ROOT) if args.out.is_relative_to(ROOT) else args.out
    print(
        f"load average (1/5/15 min): {' '.join(map(str, load_start))} at start, "
        f"{' '.join(map(str, load_end))} at end; per step in {where}"
    )

    crashed = [f"{s.key} on {LABEL[s.backend]}: {s.error}" for s in steps.values() if s.error]
    failed_targets = [f"{r['metric']} ({LABEL[b]})" for r in table for b in backends if r[b]["pass"] is False]
    combined = {
        "started_at": started.isoformat(timespec="seconds"),
        "finished_at": datetime.now(UTC).isoformat(timespec="seconds"),
        "quick": args.quick,
        "queries_scale": scale,
        "backends": backends,
        "machine": {
            **common.machine(),
            "loadavg_start": load_start,
            "loadavg_end": load_end,
        },
        "geo": geo_caps,
        "table": table,
        "notes": notes,
        "steps": {f"{k}:{b}": s.to_dict() for (k, b), s in steps.items()},
        "crashed": crashed,
        "failed_targets": failed_targets,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    common.write_json(args.out, combined)
    print(f"combined results written to {args.out}")
    if crashed:
        print("\nSTEPS THAT DID NOT COMPLETE:\n  " + "\n  ".join(crashed), file=sys.stderr)
        return 1
    if failed_targets:
        print(f"\n{len(failed_targets)} target(s) FAIL: " + "; ".join(failed_targets))
        return 1 if args.strict else 0
    return 0


if __name__ == "__main__":
    sys.exit(main())
