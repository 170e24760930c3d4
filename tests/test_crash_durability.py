"""A 200 from POST /v2/notify is a promise: the samples survive a crash.

The server answers a notification only after its samples are committed
(group commit). This test holds it to that: 16 clients send notifications
(a unique entity id and value each); once the server has acknowledged
KILL_AFTER_ACKS of them (whatever the machine's speed: the floor is a count,
not a time) it is SIGKILLed in the middle of the load, the clients keep
sending for AFTER_KILL_S more, the server is restarted on the same DuckDB
file (WAL replay) and stopped cleanly; then every acknowledged notification
must be in the file. Requests that failed when the server died are not
acknowledged and may or may not be stored.
"""

from __future__ import annotations

import signal
import time

import duckdb

from tests.support.crash_load import (
    ACK,
    FAILED,
    KILL_AFTER_ACKS,
    REFUSED,
    REJECTED,
    TENANT,
    drive_then_kill,
    entity_id,
    temperature,
)
from tests.support.rollups import differences
from tests.support.server import ServerProcess
from tsdb_service.core.config import Settings
from tsdb_service.storage import open_store


def stored_temperatures(db_path) -> dict[str, set[float]]:
    con = duckdb.connect(str(db_path), read_only=True)
    try:
        rows = con.execute(
            """
            SELECT s.entity_id, a.num
            FROM series s JOIN samples_all a ON a.sid = s.sid
            WHERE s.tenant = ? AND s.attr = 'temperature'
            """,
            [TENANT],
        ).fetchall()
    finally:
        con.close()
    stored: dict[str, set[float]] = {}
    for eid, num in rows:
        stored.setdefault(eid, set()).add(num)
    return stored


def test_acknowledged_notifications_survive_sigkill(tmp_path):
    db_path = tmp_path / "crash.duckdb"
    outcomes: dict[int, str] = {}

    server = ServerProcess(db_path)
    server.start()
    kill_codes, acked_before_kill = drive_then_kill([server], outcomes)
    assert kill_codes == [-9], f"server was not killed by SIGKILL (exit codes {kill_codes})"

    # Restart on the same file: the WAL must replay. Then stop cleanly so the
    # file can be opened here (one process per DuckDB file).
    restarted = ServerProcess(db_path)
    t_restart = time.monotonic()
    restarted.start()
    restart_s = time.monotonic() - t_restart
    exit_code = restarted.terminate()
    # uvicorn re-raises the captured SIGTERM after a graceful shutdown
    assert exit_code in (0, -signal.SIGTERM), (
        f"restarted server exited with {exit_code} after SIGTERM:\n{restarted.output()[-3000:]}"
    )

    stored = stored_temperatures(db_path)
    acked = [s for s, o in outcomes.items() if o == ACK]
    unacked = [s for s, o in outcomes.items() if o in (FAILED, REJECTED)]
    refused = [s for s, o in outcomes.items() if o == REFUSED]
    rejected = sum(1 for o in outcomes.values() if o == REJECTED)
    lost = [s for s in acked if temperature(s) not in stored.get(entity_id(s), ())]
    unacked_stored = sum(1 for s in unacked if temperature(s) in stored.get(entity_id(s), ()))
    refused_stored = sum(1 for s in refused if entity_id(s) in stored)

    summary = (
        f"crash test: {len(acked)} acknowledged, {len(lost)} lost, {len(unacked)} unacknowledged "
        f"(of which {unacked_stored} stored anyway); {acked_before_kill} acked before the kill, "
        f"{rejected} non-2xx, {len(refused)} refused after the kill, restart {restart_s:.2f} s"
    )
    print(summary)
    assert refused_stored == 0, f"{refused_stored} never-sent notifications are stored?! {summary}"
    assert len(acked) >= acked_before_kill >= KILL_AFTER_ACKS, f"too little load to mean anything: {summary}"
    assert not lost, f"acknowledged but lost, e.g. {[entity_id(s) for s in lost[:10]]}: {summary}"
    store = open_store(Settings(db=str(db_path)))  # rollups folded once per stored sample, none for the rest
    try:
        assert not differences(store)
    finally:
        store.close()
