"""An ingest-log record that stores no sample (an ``AppendSamples`` with no
entity and an MQTT delivery: the consumer's fresh-session marker once was
one) is applied once, and never leaves a start waiting.

The bug: such a record was replayed at every start, and when records the
database already held followed it, the replay left the applied sequence
number short of the acknowledged one: the next start waited for ever in
``caught_up`` (the MQTT crash test hung once in three restarts). Here the
log holds that shape exactly, and the store is started three times, each
start bounded in time.
"""

from __future__ import annotations

import threading
from datetime import UTC, datetime

import duckdb

from tests.support.ingest_log import leave_unapplied, readings
from tsdb_service.core.config import Settings
from tsdb_service.storage import open_store
from tsdb_service.write.ops import AppendSamples, Delivery

TENANT = "marked"
START_S = 30.0


def marker(seq: int) -> AppendSamples:
    delivery = Delivery("client-1", seq, 0, b"", datetime(2024, 5, 1, tzinfo=UTC), prune_below=seq)
    return AppendSamples((), deliveries=(delivery,))


def started_and_synced(db) -> None:
    """Open the store, wait for everything acknowledged to be applied, close;
    fails instead of hanging when that never happens."""
    done: list[BaseException | None] = []

    def run() -> None:
        try:
            store = open_store(Settings(db=str(db)))
            try:
                store.sync()
            finally:
                store.close()
            done.append(None)
        except BaseException as exc:
            done.append(exc)

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    thread.join(START_S)
    assert done, f"the store did not start and catch up within {START_S:.0f} s"
    if done[0] is not None:
        raise done[0]


def stored(db) -> tuple[list[float], list[tuple]]:
    con = duckdb.connect(str(db), read_only=True)
    try:
        levels = con.execute(
            "SELECT a.num FROM series s JOIN samples_all a ON a.sid = s.sid WHERE s.tenant = ? ORDER BY a.t",
            [TENANT],
        ).fetchall()
        deliveries = con.execute("SELECT client_id, seq FROM mqtt_deliveries ORDER BY seq").fetchall()
    finally:
        con.close()
    return [row[0] for row in levels], deliveries


def test_a_record_without_samples_followed_by_applied_records_never_blocks_a_start(tmp_path):
    db = tmp_path / "marked.duckdb"
    # Acknowledged, not applied: samples, the marker, more samples.
    leave_unapplied(db, [readings(TENANT, "Tank:1", [0, 1]), marker(1), readings(TENANT, "Tank:1", [2, 3])])
    started_and_synced(db)  # the replay applies all three records
    assert stored(db) == ([0.25, 1.25, 2.25, 3.25], [("client-1", 1)])
    started_and_synced(db)  # the records the database holds, the marker among them, are not replayed again
    started_and_synced(db)
    assert stored(db) == ([0.25, 1.25, 2.25, 3.25], [("client-1", 1)])


def test_a_record_without_samples_alone_at_the_end_of_the_log_is_applied_once(tmp_path):
    db = tmp_path / "marked-last.duckdb"
    leave_unapplied(db, [readings(TENANT, "Tank:1", [0]), marker(7)])
    started_and_synced(db)
    started_and_synced(db)
    assert stored(db) == ([0.25], [("client-1", 7)])
