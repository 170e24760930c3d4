"""DuckDB's write-ahead log stays bounded while a background cursor polls.

DuckDB checkpoints after a commit only when no other transaction is open.
A cursor whose last result was read with ``fetchone`` stays in a
transaction: the compactor's poll left one open between its sleeps, so under
a steady load of big batches (``import rosbag``, ``copy``, a busy service)
no commit was ever checkpointed, and the WAL and the memory holding what it
had not checkpointed grew with everything written (1.9 GB for a 1 GB bag).
"""

from __future__ import annotations

import time
from datetime import UTC, datetime
from pathlib import Path

from tests.support.samples import numbered
from tsdb_service.core.config import Settings
from tsdb_service.core.model import EntitySample
from tsdb_service.storage import open_store
from tsdb_service.write.ops import AppendSamples

KIB = 1024
THRESHOLD = 64 * KIB
START = datetime(2024, 1, 1, tzinfo=UTC)


def _batch(first: int, count: int) -> list[EntitySample]:
    return numbered("walgrowth", "Robot", ("x", "y", "z"), START, count, first=first, series=20)


def _wal_bytes(path: Path) -> int:
    wal = path.with_name(path.name + ".wal")
    return wal.stat().st_size if wal.exists() else 0


def test_the_wal_is_checkpointed_while_the_compactor_polls(tmp_path: Path):
    path = tmp_path / "h.duckdb"
    store = open_store(Settings(db=str(path), wal_checkpoint_bytes=THRESHOLD))
    try:
        store.write_sync([AppendSamples(_batch(0, 100))])
        time.sleep(2.5)  # the compactor's cursor has polled at least once
        largest = 0
        for k in range(20):
            store.write_sync([AppendSamples(_batch(100 + k * 2000, 2000))])
            store.sync()
            largest = max(largest, _wal_bytes(path))
        # One batch's records past the threshold at most, not everything written.
        assert largest < 2 * 1024 * KIB, f"the WAL grew to {largest:,} bytes"
    finally:
        store.close()
