"""Retention benchmark: the cost of retention batches, raw and rollup levels.

    .venv/bin/python benchmarks/retention.py                      # 10M samples, DuckDB
    .venv/bin/python benchmarks/retention.py --scale 0.1          # 1M samples
    .venv/bin/python benchmarks/retention.py --backend postgresql [--scale 0.1] [--json FILE]

1. Loads 1,000 entities x 10 attributes x (1,000 x scale) samples in-process
   through the store's write path (``write_sync`` with big ``AppendSamples``
   batches, as ``queries.py`` does), spread over 25 hours whatever the scale,
   then compacts (DuckDB) or runs VACUUM ANALYZE (PostgreSQL).
2. Runs two retention passes with a clock set inside the data, each deleting
   about a third of the raw samples (rollups, kept on ingest, stay): the
   first of raw samples only, the second also of the minute rollups of the
   first third (``TSDB_RETENTION=*=raw:...,minute:...``), with
   ``--batch-rows`` rows per batch and no pause. Meanwhile a probe thread
   commits one notification (10 samples) and runs one hourly average over
   hours only rollups hold, alternately, and records their latencies, also
   with retention idle.
3. Prints rows deleted per second, batch time p50/p99/max for each pass, the
   probe's latencies idle and during each pass, and an hourly average over
   data that is only in rollups.
"""

from __future__ import annotations

import argparse
import json
import random
import sys
import tempfile
import threading
import time
from datetime import UTC, datetime, timedelta
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import common
from common import bulk_load, finish_load, is_pg, open_store
from common import percentiles as pct
from pgutil import BenchCluster

ENTITIES = 1_000
ATTRS = 10
SAMPLES = 1_000
SPAN = timedelta(hours=25)
START = datetime(2024, 5, 1, tzinfo=UTC)
KEEP = timedelta(days=1)


def load(db, per_series: int, cluster, batch_notifications: int = 20_000) -> dict:
    from tsdb_service.core.model import AttrSample, EntitySample, Kind

    step = SPAN / per_series
    rng = random.Random(7)

    def steps():
        for i in range(per_series):
            moment = START + i * step
            yield [
                EntitySample(
                    "",
                    "/",
                    f"urn:ngsi-ld:Robot:{e:04d}",
                    "Robot",
                    moment,
                    [AttrSample(f"attr{a}", "Number", Kind.NUMBER, num=e + a + rng.random()) for a in range(ATTRS)],
                )
                for e in range(ENTITIES)
            ]

    store, written, load_s = bulk_load(db, steps(), batch_notifications)
    print(f"loaded {written:,} samples in {load_s:.0f} s", flush=True)
    return {"samples": written, "load_s": round(load_s, 1), **finish_load(store, db, cluster)}


class Batches:
    def __init__(self):
        self.seconds: list[float] = []
        self.rows = 0

    def batch(self, table, tenant, rows, seconds) -> None:
        self.seconds.append(seconds)
        self.rows += rows


class Probe:
    """Alternately commits one notification and runs one hourly average over
    a day, recording latencies until stopped."""

    def __init__(self, store, day_start: datetime):
        from tsdb_service.core.query import (
            AggBranch,
            Aggregation,
            AggrMethod,
            AggrPeriod,
            EntityFilter,
            Scope,
            TimeRange,
        )
        from tsdb_service.read.requests import AggregateRead, SeriesSelect

        self.store = store
        self.ask = AggregateRead
        q = store.querier()
        self.q = q
        self.refs = q.series(SeriesSelect(Scope(""), EntityFilter(types=("Robot",)), {"attr0"}))
        self.branch = AggBranch
        self.agg = Aggregation(AggrMethod.AVG, AggrPeriod.HOUR)
        self.window = TimeRange(day_start, day_start + timedelta(hours=8))
        self.stop = threading.Event()
        self.commit_ms: list[float] = []
        self.query_ms: list[float] = []

    def _commit(self, n: int) -> None:
        from tsdb_service.core.model import AttrSample, EntitySample, Kind
        from tsdb_service.write.ops import AppendSamples

        attrs = [AttrSample(f"attr{a}", "Number", Kind.NUMBER, num=float(a)) for a in range(ATTRS)]
        moment = START + SPAN + timedelta(seconds=n)
        self.store.write_sync([AppendSamples([EntitySample("", "/", "probe", "Probe", moment, attrs)])])

    def run(self) -> None:
        rng = random.Random(3)
        n = 0
        while not self.stop.is_set():
            t0 = time.perf_counter()
            self._commit(n)
            self.commit_ms.append((time.perf_counter() - t0) * 1000)
            ref = rng.choice(self.refs)
            t0 = time.perf_counter()
            self.q.aggregate(self.ask([self.branch((ref.sid,))], self.window, self.agg))
            self.query_ms.append((time.perf_counter() - t0) * 1000)
            n += 1
            time.sleep(0.01)

    def measure(self, during) -> dict:
        self.commit_ms, self.query_ms = [], []
        self.stop.clear()
        thread = threading.Thread(target=self.run, daemon=True)
        thread.start()
        try:
            result = during()
        finally:
            self.stop.set()
            thread.join()
        return {"result": result, "commit_ms": pct(self.commit_ms), "query_ms": pct(self.query_ms)}


def one_pass(store, retention: str, clock_at: datetime, batch_rows: int) -> dict:
    from tsdb_service.core.config import Settings
    from tsdb_service.storage.retention import attach_retention

    settings = Settings(
        db="unused",
        retention=retention,
        retention_pause=0,
        retention_batch_rows=batch_rows,
    )
    worker = attach_retention(store, settings, start=False, clock=lambda: clock_at)
    batches = worker.observer = Batches()
    t0 = time.perf_counter()
    worker.run_once()
    seconds = time.perf_counter() - t0
    return {
        "rows": batches.rows,
        "seconds": round(seconds, 2),
        "rows_per_s": round(batches.rows / seconds),
        "batches": len(batches.seconds),
        "batch_ms": pct([s * 1000 for s in batches.seconds]),
    }


def rolled_up_query_ms(store, probe) -> dict:
    """An hourly average over 8 hours that only rollups hold."""
    from tsdb_service.core.query import TimeRange
    from tsdb_service.read.requests import AggregateRead

    window = TimeRange(START + timedelta(hours=9), START + timedelta(hours=17))
    times = []
    for ref in probe.refs[:200]:
        t0 = time.perf_counter()
        rows = probe.q.aggregate(AggregateRead([probe.branch((ref.sid,))], window, probe.agg))
        times.append((time.perf_counter() - t0) * 1000)
        assert rows, "nothing rolled up"
    return pct(times)


def run(db, cluster, args) -> dict:
    per_series = max(1, round(SAMPLES * args.scale))
    out = {"backend": "postgresql" if is_pg(db) else "duckdb", "scale": args.scale, "batch_rows": args.batch_rows}
    out["load"] = load(db, per_series, cluster)
    store = open_store(db)
    try:
        probe = Probe(store, START + timedelta(hours=9))
        out["idle"] = probe.measure(lambda: time.sleep(2.0))
        keep = int(KEEP.total_seconds())
        # Pass 1, raw samples: everything before START + 8h20m goes (a third); rollups stay.
        first = probe.measure(lambda: one_pass(store, f"*={keep}s", START + SPAN / 3 + KEEP, args.batch_rows))
        out["pass_raw"] = {**first.pop("result"), **first}
        print("raw          ", json.dumps(out["pass_raw"]), flush=True)
        # Pass 2, raw samples up to START + 16h40m, and the minute rollups of the first third.
        minute = keep + int(SPAN.total_seconds()) // 3
        second = probe.measure(
            lambda: one_pass(store, f"*=raw:{keep}s,minute:{minute}s", START + 2 * SPAN / 3 + KEEP, args.batch_rows)
        )
        out["pass_raw_and_minute"] = {**second.pop("result"), **second}
        print("raw + minute ", json.dumps(out["pass_raw_and_minute"]), flush=True)
        out["rolled_up_hourly_avg_8h_ms"] = rolled_up_query_ms(store, probe)
    finally:
        store.close()
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--backend", choices=("duckdb", "postgresql"), default="duckdb")
    parser.add_argument("--scale", type=float, default=1.0, help="x 1,000 samples per series (1 = 10M samples)")
    parser.add_argument("--batch-rows", type=int, default=50_000, help="rows per batch (TSDB_RETENTION_BATCH_ROWS)")
    parser.add_argument("--json", type=Path, help="write the results here too")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="tsdb-retention-") as tmp:
        if args.backend == "postgresql":
            print("starting a private PostgreSQL cluster ...", flush=True)
            with BenchCluster("retention") as cluster:
                result = run(cluster.url, cluster, args)
        else:
            result = run(str(Path(tmp) / "bench.duckdb"), None, args)
    print(json.dumps(result, indent=2))
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        common.write_json(args.json, result)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
