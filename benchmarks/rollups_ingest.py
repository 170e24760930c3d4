"""Ingest with and without rollup maintenance: a micro-benchmark (issue 38).

    .venv/bin/python benchmarks/rollups_ingest.py                    # DuckDB and PostgreSQL
    .venv/bin/python benchmarks/rollups_ingest.py --backends duckdb --rounds 50

Commits batches of notifications (entities x 5 numeric attributes, one
sample a second each, as the long-window benchmark loads) through the
writer, on a fresh store per mode: with the rollups folded in each commit's
transaction (what the service does) and without, at three batch sizes:
100 rows (light traffic's small group: DuckDB's writer aggregates it in
Python and appends it), 2,000 rows and 50,000 rows (the ingest log's
applier under load; one SQL statement over the Arrow batch).

* **DuckDB**: the writer itself (``DuckDBAppender``), and a subclass
  without its ``_fold_rollups`` step. The compactor merges hot rollup rows
  in the background meanwhile; the run ends with a full merge
  (``compact``), whose time is counted.
* **PostgreSQL**: ``write_sync`` on a private durable cluster, the
  ``rollups_fold`` trigger enabled or disabled; the merger thread runs
  meanwhile, and a full merge ends the run.

Prints, per batch size and mode, the median commit time, and the run's
total (every commit and the final merge) per 1,000 samples; for DuckDB
also the process's CPU time per 1,000 samples (the compactor's merges
included). One machine, one run: indicative only, and meaningless while
other work shares the cores.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from datetime import UTC, datetime, timedelta
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from tsdb_service.core.model import AttrSample, EntitySample, Kind  # noqa: E402
from tsdb_service.write.ops import AppendSamples  # noqa: E402

ATTRS = ("batteryLevel", "speed", "bladeSpeed", "cutHeight", "motorTemperature")
START = datetime(2024, 5, 1, tzinfo=UTC)
SIZES = (100, 2_000, 50_000)  # rows (samples) per batch


def batch(rows: int, second: int) -> list[EntitySample]:
    """``rows`` samples: ``rows / 5`` entities at one second each."""
    entities = rows // len(ATTRS)
    out = []
    for e in range(entities):
        at = START + timedelta(seconds=second + e // 200)
        attrs = [AttrSample(a, "Number", Kind.NUMBER, num=(e * 7 + i) % 97 / 4) for i, a in enumerate(ATTRS)]
        out.append(EntitySample("bench", "/", f"Lawnmower:{e % 200}", "Lawnmower", at, attrs))
    return out


def duckdb_run(rounds: int) -> dict[tuple[int, str], tuple[float, float, float]]:
    """(batch size, mode) → (median commit s, total s per 1k rows, CPU s per 1k rows)."""
    from tsdb_service.storage.duckdb.appender import DuckDBAppender
    from tsdb_service.storage.duckdb.store import DuckDBStore

    class WithoutRollups(DuckDBAppender):
        def _fold_rollups(self, cur) -> None:
            pass

    out = {}
    for rows in SIZES:
        n = rounds if rows < 50_000 else max(3, rounds // 10)
        for mode, writer_type in (("without", WithoutRollups), ("with", DuckDBAppender)):
            with tempfile.TemporaryDirectory() as tmp:
                store = DuckDBStore(str(Path(tmp) / "bench.duckdb"), ingest_log=False)
                try:
                    writer = writer_type(store)
                    times = []
                    cpu0, wall0 = time.process_time(), time.perf_counter()
                    for k in range(n):
                        writer.stage(AppendSamples(batch(rows, 60 * k), dedup=False))
                        t0 = time.perf_counter()
                        writer.commit()
                        times.append(time.perf_counter() - t0)
                    store.compact(full=False)  # what is left to merge
                    wall, cpu = time.perf_counter() - wall0, time.process_time() - cpu0
                finally:
                    store.close()
            per_k = 1000 / (rows * n)
            out[(rows, mode)] = (statistics.median(times), wall * per_k, cpu * per_k)
    return out


def postgres_run(rounds: int) -> dict[tuple[int, str], tuple[float, float, float]]:
    import psycopg
    from pgutil import BenchCluster

    from tsdb_service.core.config import Settings
    from tsdb_service.storage import open_store

    out = {}
    with BenchCluster("rollups_ingest") as cluster:
        for rows in SIZES:
            n = rounds if rows < 50_000 else max(3, rounds // 10)
            for mode in ("without", "with"):
                url = cluster.cluster.database(f"rollups_{rows}_{mode}")
                store = open_store(Settings(db=url))
                try:
                    switch = "ENABLE" if mode == "with" else "DISABLE"
                    with psycopg.connect(url, autocommit=True) as conn:
                        conn.execute(f"ALTER TABLE samples {switch} TRIGGER rollups_fold")
                    store.write_sync([AppendSamples(batch(100, -3600), dedup=False)])  # series known: the COPY path
                    times = []
                    wall0 = time.perf_counter()
                    for k in range(n):
                        ops = [AppendSamples(batch(rows, 60 * k), dedup=False)]
                        t0 = time.perf_counter()
                        store.write_sync(ops)
                        times.append(time.perf_counter() - t0)
                    store.compact()  # what is left to merge
                    wall = time.perf_counter() - wall0
                finally:
                    store.close()
                out[(rows, mode)] = (statistics.median(times), wall * 1000 / (rows * n), float("nan"))
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--backends", default="duckdb,postgresql", help="comma list (default: both)")
    parser.add_argument("--rounds", type=int, default=30, help="commits per batch size and mode (default 30)")
    args = parser.parse_args()
    print("one machine, one run: indicative only")
    print(f"{'backend':<11}{'rows':>7}  {'commit p50 ms':>22}  {'total ms / 1k rows':>22}  {'CPU ms / 1k rows':>20}")
    print(f"{'':<11}{'':>7}  {'without':>10} {'with':>11}  {'without':>10} {'with':>11}  {'without':>9} {'with':>10}")
    for backend in args.backends.split(","):
        run = {"duckdb": duckdb_run, "postgresql": postgres_run}[backend.strip()]
        figures = run(args.rounds)
        for rows in SIZES:
            a, b = figures[(rows, "without")], figures[(rows, "with")]
            print(
                f"{backend:<11}{rows:>7}  {a[0] * 1000:>10.2f} {b[0] * 1000:>11.2f}  "
                f"{a[1] * 1000:>10.2f} {b[1] * 1000:>11.2f}  {a[2] * 1000:>9.2f} {b[2] * 1000:>10.2f}"
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
