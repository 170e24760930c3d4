"""CPU of the DuckDB writer's apply step per sample, in process, by batch size.

    .venv/bin/python benchmarks/apply_cpu.py                       # 10, 50, 200, 500 notifications a batch
    .venv/bin/python benchmarks/apply_cpu.py --batches 10 200 --rounds 5
    .venv/bin/py-spy record --gil --format raw -o /tmp/apply.txt -- .venv/bin/python benchmarks/apply_cpu.py

What stays in the process owning the DuckDB file once the HTTP work moves
out is the ingest log's applier: ``DuckDBAppender.stage`` then ``commit``
of each batch of notifications (the rows, their minute and hour rollups,
the ingest log's position, then the memory: tails, hourly partials,
latest locations). This times exactly that on a temporary file, with the
ingest benchmark's notifications (``lawnmower.ingest_body``: one Lawnmower
entity of six samples each, parsed by the real parser beforehand), each
entity given its row id as the ingest log does.

Per batch size it runs ``--rounds`` rounds of ``--commits`` batches (after
one warm-up round, so every series exists) and prints, per round, the
writer thread's CPU per sample (``time.thread_time``: what the thread ran,
in Python or in DuckDB, on its core; barely moved by other load), and the
process's CPU per sample (DuckDB's own threads too); then the median. The
interpreter-lock share is not measured here: run it under ``py-spy record
--gil`` (above), or see ``ingest_cpu.py --profile --gil``.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import statistics
import sys
import tempfile
import time
from datetime import UTC, datetime
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import lawnmower

from tsdb_service.core.config import Settings
from tsdb_service.core.model import EntitySample
from tsdb_service.parse.notification import parse_notification
from tsdb_service.storage import open_store
from tsdb_service.storage.duckdb.appender import DuckDBAppender
from tsdb_service.storage.duckdb.store import DuckDBStore
from tsdb_service.write.ops import AppendSamples, LogPosition

POOL = 1000  # entities, as ingest_cpu.py's load


def notifications(count: int, first_seq: int) -> list[EntitySample]:
    out: list[EntitySample] = []
    headers = lawnmower.headers(lawnmower.INGEST_TENANT)
    now = datetime.now(UTC)
    for seq in range(first_seq, first_seq + count):
        out += parse_notification(lawnmower.ingest_body("apply", seq, POOL), headers, received_at=now)
    return out


def batches(per_batch: int, commits: int, first_seq: int, first_rid: int) -> list[AppendSamples]:
    """``commits`` batches of ``per_batch`` notifications, row ids given (the ingest log's)."""
    out = []
    entities = notifications(per_batch * commits, first_seq)
    for b in range(commits):
        group = []
        for i, e in enumerate(entities[b * per_batch : (b + 1) * per_batch]):
            group.append(dataclasses.replace(e, rid=first_rid + b * per_batch + i))
        out.append(AppendSamples(group, log_position=LogPosition(first_seq + (b + 1) * per_batch, group[-1].rid)))
    return out


def one_round(appender: DuckDBAppender, ops: list[AppendSamples]) -> tuple[float, float, float]:
    """(thread CPU s, process CPU s, wall s) of staging and committing ``ops``, one commit each."""
    thread0, process0, wall0 = time.thread_time(), time.process_time(), time.perf_counter()
    for op in ops:
        appender.stage(op)
        appender.commit()
    return time.thread_time() - thread0, time.process_time() - process0, time.perf_counter() - wall0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--batches", type=int, nargs="+", default=[10, 50, 200, 500], help="notifications a batch")
    parser.add_argument("--commits", type=int, default=0, help="batches a round (default: about 6,000 samples)")
    parser.add_argument("--rounds", type=int, default=3)
    args = parser.parse_args()
    print(f"load average {os.getloadavg()[0]:.2f}; thread / process CPU us per sample (6 samples a notification)")
    with tempfile.TemporaryDirectory() as tmp:
        store = open_store(Settings(db=str(Path(tmp) / "apply.duckdb"), ingest_log=False))
        assert isinstance(store, DuckDBStore)
        appender = DuckDBAppender(store)
        seq = rid = 1
        try:
            warm = batches(100, POOL // 100, seq, store.ids.take_rids(POOL))
            seq += POOL
            one_round(appender, warm)
            for per_batch in args.batches:
                commits = args.commits or max(2, 1000 // per_batch)
                samples = per_batch * commits * 6
                thread_us, process_us = [], []
                for _ in range(args.rounds):
                    rid = store.ids.take_rids(per_batch * commits)
                    ops = batches(per_batch, commits, seq, rid)
                    seq += per_batch * commits
                    thread_s, process_s, _ = one_round(appender, ops)
                    thread_us.append(thread_s * 1e6 / samples)
                    process_us.append(process_s * 1e6 / samples)
                rounds = "  ".join(f"{t:.2f}/{p:.2f}" for t, p in zip(thread_us, process_us, strict=True))
                print(
                    f"{per_batch:4d} notifications ({per_batch * 6:5d} samples) a batch: {rounds}  "
                    f"median {statistics.median(thread_us):.2f}/{statistics.median(process_us):.2f}"
                )
        finally:
            appender.close()
            store.close()


if __name__ == "__main__":
    main()
