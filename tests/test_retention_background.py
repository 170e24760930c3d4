"""The retention worker on its own: a running server applies the policy in
the background, in small batches, while notifications keep arriving, and
every acknowledged sample inside the retention window is kept."""

from __future__ import annotations

import time
from datetime import UTC, datetime, timedelta

NOW = datetime.now(UTC).replace(microsecond=0)
H = {"Fiware-Service": "acme"}


def batch(eid: str, start: datetime, n: int, first: int = 0) -> dict:
    return {
        "subscriptionId": "s",
        "data": [
            {
                "id": eid,
                "type": "Robot",
                "x": {"type": "Integer", "value": first + i},
                "TimeInstant": {"type": "DateTime", "value": (start + timedelta(seconds=i)).isoformat()},
            }
            for i in range(n)
        ],
    }


def counts(client) -> tuple[int, int]:
    """(old, new) samples of attribute x, straight from the database."""
    q = client.app.state.store.querier()
    cutoff = (NOW - timedelta(days=5)).replace(tzinfo=None)
    old = q._fetch(f"SELECT count(*) FROM samples_all WHERE t < {q.dialect.placeholder}", [cutoff])[0][0]
    new = q._fetch(f"SELECT count(*) FROM samples_all WHERE t >= {q.dialect.placeholder}", [cutoff])[0][0]
    return old, new


def wait_for(predicate, timeout: float = 20.0) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(0.05)
    return predicate()


def test_the_worker_deletes_in_the_background_while_ingest_goes_on(client_factory, store_url, notify):
    settings = dict(
        retention="acme=10d", rollups=True, retention_interval=0.05, retention_batch_rows=25, retention_pause=0.001
    )
    with client_factory(store_url, **settings) as client:
        notify(client, batch("Old", NOW - timedelta(days=20), 300), H)
        acked_new = 0
        for k in range(10):  # keeps arriving while passes run
            notify(client, batch("New", NOW - timedelta(days=1), 20, first=k * 20), H)
            notify(client, batch("Old", NOW - timedelta(days=20, hours=k + 1), 5), H)
            acked_new += 20
        worker = client.app.state.store.retention
        after_ingest = worker.passes
        assert wait_for(lambda: worker.passes >= after_ingest + 2), "no complete pass"  # one began after ingest
        assert counts(client) == (0, 2 * acked_new)  # x and TimeInstant of every new notification kept
        assert worker.batches > 350 * 2 // 25
        total = client.get("/v2/entities/Old/attrs/x?aggrMethod=count", headers=H).json()
        assert total["values"] == [350]  # all of it rolled up
        text = client.get("/metrics").text
        assert 'tsdb_retention_deleted_rows_total{table="samples' in text
