"""The crash promise on PostgreSQL, with two service processes writing at once.

Two replicas share one database; 16 clients spread over both send
notifications; both are SIGKILLed mid-load. After a restart, every
notification either replica acknowledged must be in the database.
"""

from __future__ import annotations

import os

import psycopg
import pytest

from tests.support.crash_load import (
    ACK,
    FAILED,
    KILL_AFTER_ACKS,
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


def stored_temperatures(url: str) -> dict[str, set[float]]:
    with psycopg.connect(url) as conn:
        rows = conn.execute(
            "SELECT s.entity_id, x.num FROM samples x JOIN series s USING (sid) "
            "WHERE s.tenant = %s AND s.attr = 'temperature'",
            [TENANT],
        ).fetchall()
    stored: dict[str, set[float]] = {}
    for eid, num in rows:
        stored.setdefault(eid, set()).add(num)
    return stored


@pytest.mark.skipif(
    "postgresql" not in os.environ.get("TSDB_TEST_BACKENDS", "postgresql"),
    reason="PostgreSQL is not among TSDB_TEST_BACKENDS",
)
def test_two_replicas_lose_nothing_acknowledged_on_sigkill(pg_cluster):
    url = pg_cluster.database("crash_two_replicas")
    replicas = [ServerProcess(url).start(), ServerProcess(url).start()]
    outcomes: dict[int, str] = {}
    codes, acked_before_kill = drive_then_kill(replicas, outcomes)
    assert codes == [-9, -9]

    restarted = ServerProcess(url).start()  # migrations and health on a crashed database
    restarted.terminate()

    stored = stored_temperatures(url)
    acked = [s for s, o in outcomes.items() if o == ACK]
    unacked = [s for s, o in outcomes.items() if o in (FAILED, REJECTED)]
    lost = [s for s in acked if temperature(s) not in stored.get(entity_id(s), ())]
    print(
        f"crash test (PostgreSQL, 2 replicas): {len(acked)} acknowledged, {len(lost)} lost, "
        f"{len(unacked)} unacknowledged"
    )
    assert len(acked) >= acked_before_kill >= KILL_AFTER_ACKS
    assert not lost, f"acknowledged but lost: {[entity_id(s) for s in lost[:10]]}"
    store = open_store(Settings(db=url))  # each committed sample rolled up once, by its transaction
    try:
        assert not differences(store)
    finally:
        store.close()
