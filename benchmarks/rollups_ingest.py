"""Ingest with and without rollup maintenance: a micro-benchmark (issue 38).

    .venv/bin/python benchmarks/rollups_ingest.py                    # DuckDB and PostgreSQL
    .venv/bin/python benchmarks/rollups_ingest.py --backends duckdb --rounds 50

Commits batches of notifications (entities x 5 numeric attributes, one
sample a second each, as the long-window benchmark loads) through the writer, and
times each commit twice over: with the rollups folded in the commit's
transaction (what the service does) and without.

* **DuckDB**: the writer itself (``DuckDBAppender``) with and without its
  ``_fold_rollups`` step, on one file, alternately, at three batch sizes:
  100 rows (a DuckDB appender, the small group of light traffic), 2,000
  rows and 50,000 rows (Arrow; the ingest log's applier under load).
* **PostgreSQL**: ``write_sync`` on a private durable cluster with the
  ``rollups_fold`` trigger enabled and disabled, alternately.

Prints the median commit time per batch size and mode, and the cost per
1,000 samples. One machine, one run: indicative only, and meaningless while
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


def duckdb_run(rounds: int) -> dict[tuple[int, str], float]:
    from tsdb_service.storage.duckdb.appender import DuckDBAppender
    from tsdb_service.storage.duckdb.store import DuckDBStore

    class WithoutRollups(DuckDBAppender):
        def _fold_rollups(self, cur) -> None:
            pass

    out = {}
    with tempfile.TemporaryDirectory() as tmp:
        store = DuckDBStore(str(Path(tmp) / "bench.duckdb"), ingest_log=False)
        try:
            writers = {"with": DuckDBAppender(store), "without": WithoutRollups(store)}
            second = 0
            for rows in SIZES:
                times: dict[str, list[float]] = {"with": [], "without": []}
                n = rounds if rows < 50_000 else max(3, rounds // 10)
                for _ in range(n):
                    for mode, writer in writers.items():
                        second += 60
                        writer.stage(AppendSamples(batch(rows, second), dedup=False))
                        t0 = time.perf_counter()
                        writer.commit()
                        times[mode].append(time.perf_counter() - t0)
                for mode, seen in times.items():
                    out[(rows, mode)] = statistics.median(seen)
        finally:
            store.close()
    return out


def postgres_run(rounds: int) -> dict[tuple[int, str], float]:
    import psycopg
    from pgutil import BenchCluster

    from tsdb_service.core.config import Settings
    from tsdb_service.storage import open_store

    out = {}
    with BenchCluster("rollups_ingest") as cluster:
        store = open_store(Settings(db=cluster.url))
        try:
            with psycopg.connect(cluster.url, autocommit=True) as conn:
                second = 0
                store.write_sync([AppendSamples(batch(100, second), dedup=False)])  # series exist: the COPY path
                for rows in SIZES:
                    times: dict[str, list[float]] = {"with": [], "without": []}
                    n = rounds if rows < 50_000 else max(3, rounds // 10)
                    for _ in range(n):
                        for mode in ("with", "without"):
                            switch = "ENABLE" if mode == "with" else "DISABLE"
                            conn.execute(f"ALTER TABLE samples {switch} TRIGGER rollups_fold")
                            second += 60
                            ops = [AppendSamples(batch(rows, second), dedup=False)]
                            t0 = time.perf_counter()
                            store.write_sync(ops)
                            times[mode].append(time.perf_counter() - t0)
                    for mode, seen in times.items():
                        out[(rows, mode)] = statistics.median(seen)
                conn.execute("ALTER TABLE samples ENABLE TRIGGER rollups_fold")
        finally:
            store.close()
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--backends", default="duckdb,postgresql", help="comma list (default: both)")
    parser.add_argument("--rounds", type=int, default=30, help="commits per batch size and mode (default 30)")
    args = parser.parse_args()
    print("commit time, median (ms); one machine, one run: indicative only")
    print(f"{'backend':<11}{'rows':>8}{'without':>11}{'with':>11}{'added':>10}{'per 1k rows':>13}")
    for backend in args.backends.split(","):
        run = {"duckdb": duckdb_run, "postgresql": postgres_run}[backend.strip()]
        figures = run(args.rounds)
        for rows in SIZES:
            without, with_ = figures[(rows, "without")] * 1000, figures[(rows, "with")] * 1000
            added = with_ - without
            print(f"{backend:<11}{rows:>8}{without:>11.2f}{with_:>11.2f}{added:>+10.2f}{added / rows * 1000:>+13.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
