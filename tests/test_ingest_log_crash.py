"""A crash while the ingest log is being replayed loses nothing and stores
nothing twice (DuckDB: PostgreSQL keeps no ingest log).

The log is left as a crash leaves it: records acknowledged (durable in the
log) and not applied. The service starts and replays them; it is SIGKILLed
once the first batches are applied and others are not; it starts again,
finishes the replay, and stops cleanly. Every notification is then in the
file exactly once, with its value.
"""

from __future__ import annotations

import re
import time
import urllib.request
from datetime import UTC, datetime, timedelta

import duckdb

from tests.support.ingest_log import leave_unapplied
from tests.support.rollups import differences
from tests.support.server import ServerProcess
from tsdb_service.core.config import Settings
from tsdb_service.core.model import AttrSample, EntitySample, Kind
from tsdb_service.storage import open_store
from tsdb_service.write.ops import AppendSamples

TENANT = "replay"
ENTITIES = 60_000  # two batches of APPLY_ROWS (50,000 samples)
PER_RECORD = 200
T0 = datetime(2024, 5, 1, tzinfo=UTC)


def _leave_a_crashed_log(db_path) -> None:
    records = []
    for start in range(0, ENTITIES, PER_RECORD):
        entities = []
        for n in range(start, start + PER_RECORD):
            sample = AttrSample("level", "Number", Kind.NUMBER, num=n + 0.25)
            entities.append(EntitySample(TENANT, "/", f"Tank:{n}", "Tank", T0 + timedelta(seconds=n), [sample]))
        records.append(AppendSamples(entities))
    leave_unapplied(db_path, records)


def _metric(server: ServerProcess, name: str) -> float:
    with urllib.request.urlopen(server.url + "/metrics", timeout=10) as answer:
        text = answer.read().decode()
    return float(re.search(rf"^{name}(?:_total)? (\S+)$", text, re.M).group(1))


def _wait(condition, timeout: float = 120.0) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.02)


def test_a_kill_during_replay_loses_and_doubles_nothing(tmp_path):
    db_path = tmp_path / "replay.duckdb"
    _leave_a_crashed_log(db_path)

    server = ServerProcess(db_path)
    server.start()
    _wait(lambda: _metric(server, "tsdb_ingest_log_applied_batches") >= 1)
    lag_at_kill = _metric(server, "tsdb_ingest_log_lag_records")
    server.kill()
    assert lag_at_kill > 0, "the replay ended before the kill: make ENTITIES larger"

    again = ServerProcess(db_path)
    again.start()
    _wait(lambda: _metric(again, "tsdb_ingest_log_lag_records") == 0)
    again.terminate()

    con = duckdb.connect(str(db_path), read_only=True)
    try:
        rows = con.execute(
            "SELECT s.entity_id, a.num FROM series s JOIN samples_all a ON a.sid = s.sid WHERE s.tenant = ?",
            [TENANT],
        ).fetchall()
    finally:
        con.close()
    assert len(rows) == ENTITIES  # nothing doubled
    assert dict(rows) == {f"Tank:{n}": n + 0.25 for n in range(ENTITIES)}  # nothing lost or altered
    store = open_store(Settings(db=str(db_path)))
    try:
        assert not differences(store)  # no batch rolled up twice (the position moves in its transaction)
    finally:
        store.close()
