"""DuckDB's WAL checkpoint threshold (``TSDB_WAL_CHECKPOINT_BYTES``).

The commit that crosses the threshold runs the checkpoint while every
notification queued behind it waits, so the default is smaller than
DuckDB's own (4 against 16 MiB). The threshold is set on the database
instance after connecting, not passed as a connect() option: DuckDB refuses
a second in-process connection to a file opened with another
configuration, and the service's plain connections (migrate, probes) must
keep working next to an open store.
"""

from __future__ import annotations

from datetime import UTC, datetime, timedelta
from pathlib import Path

import duckdb

from tests.support.samples import numbered
from tsdb_service import storage
from tsdb_service.core.config import WAL_CHECKPOINT_BYTES, Settings
from tsdb_service.core.model import EntitySample
from tsdb_service.storage import open_store
from tsdb_service.storage.duckdb.connection import connect
from tsdb_service.write.ops import AppendSamples

KIB = 1024


def _threshold(con: duckdb.DuckDBPyConnection) -> str:
    """DuckDB's own rendering of the setting, e.g. ``4.0 MiB``."""
    return con.execute("SELECT current_setting('wal_autocheckpoint')").fetchone()[0]


def _notifications(count: int, start: datetime) -> list[EntitySample]:
    return numbered("walck", "Lawnmower", ("speed", "left", "right"), start, count, series=50)


def test_default_is_four_mib_not_duckdbs_sixteen():
    assert WAL_CHECKPOINT_BYTES == 4 * 1024 * KIB
    assert Settings().wal_checkpoint_bytes == WAL_CHECKPOINT_BYTES


def test_store_sets_the_threshold_on_its_database(tmp_path: Path):
    for wanted, shown in ((None, "4.0 MiB"), (64 * KIB, "64.0 KiB")):
        path = tmp_path / f"{wanted}.duckdb"
        settings = Settings(db=str(path)) if wanted is None else Settings(db=str(path), wal_checkpoint_bytes=wanted)
        store = open_store(settings)
        try:
            assert _threshold(store.cursor()) == shown
        finally:
            store.close()


def test_plain_connections_share_the_configured_database(tmp_path: Path):
    path = str(tmp_path / "shared.duckdb")
    writer = connect(path, checkpoint_bytes=64 * KIB)
    try:
        other = duckdb.connect(path)  # refused when the threshold was a connect() option
        try:
            assert _threshold(other) == "64.0 KiB"
        finally:
            other.close()
        # the migrate command opens its own plain connection to the same file
        assert storage.migrate(Settings(db=path))
        assert storage.migrate(Settings(db=path)) == []
    finally:
        writer.close()


def test_the_wal_is_folded_once_past_the_threshold(tmp_path: Path):
    """Writing many times the threshold leaves a WAL smaller than it plus one
    group: each crossing commit checkpointed."""
    path = tmp_path / "fold.duckdb"
    store = open_store(Settings(db=str(path), wal_checkpoint_bytes=64 * KIB))
    start = datetime(2026, 1, 1, tzinfo=UTC)
    try:
        for k in range(40):
            store.write_sync([AppendSamples(_notifications(100, start + timedelta(minutes=k)))])
        wal = Path(str(path) + ".wal")
        assert not wal.exists() or wal.stat().st_size < 64 * KIB + 256 * KIB
        assert store.cursor().execute("SELECT count(*) FROM samples_all").fetchone()[0] == 12_000
    finally:
        store.close()
