"""Disk full during a DuckDB checkpoint: acknowledged once, 503 meanwhile, reopened after.

When the automatic checkpoint after a commit cannot write the file, DuckDB
says "COMMIT succeeded and is durable, but the autocheckpoint failed" and
invalidates the database instance. The commit must be acknowledged (it is
stored), every later call answered 503 (never 500, never a false "nothing
was stored"), ``/health`` must fail, and once there is space again the store
must reopen the file by itself, with every acknowledged notification stored
exactly once. The database lives on a small tmpfs filled by the test.
"""

from __future__ import annotations

import json
import time

import pytest

from tests.support.disk_full import (
    ENTITY,
    HEADERS,
    READ_HEADERS,
    Outcomes,
    check_exactly_once,
    health,
    stored_seqs,
    wait_healthy,
)
from tests.support.tmpfs import fill, small_tmpfs
from tsdb_service.storage.duckdb import store as duckdb_store

CHECKPOINT_BYTES = 64 * 1024  # the WAL is folded into the file every ~60 notifications
LEAVE_BYTES = 160 * 1024  # room for the WAL to reach that size, not for the checkpoint
MAX_POSTS = 2000


def poster(client):
    def post(method: str, path: str, body: bytes | None):
        headers = HEADERS if method == "POST" else READ_HEADERS
        response = client.request(method, path, content=body, headers=headers)
        assert response.status_code != 500, response.text
        return response.status_code, json.loads(response.content or b"{}")

    return post


def break_store(post, outcomes: Outcomes) -> dict:
    """Post until /health fails; return its report."""
    for _ in range(MAX_POSTS):
        outcomes.send(post)
        status, report = health(post)
        if status != 200:
            assert status == 503 and report["status"] == "fail", report
            return report
    raise AssertionError(f"the store never failed after {MAX_POSTS} notifications on a full disk")


@pytest.fixture
def slow_reopen(monkeypatch):
    """First reopen attempt after 2 s: long enough to look at the broken store."""
    monkeypatch.setattr(duckdb_store, "REOPEN_DELAY_S", 2.0)
    monkeypatch.setattr(duckdb_store, "REOPEN_MAX_DELAY_S", 2.0)


def test_checkpoint_failure_is_acknowledged_and_the_store_reopens(tmp_path, client_factory, slow_reopen):
    with small_tmpfs(tmp_path / "disk", "24m") as disk:
        with client_factory(str(disk / "tsdb.duckdb"), wal_checkpoint_bytes=CHECKPOINT_BYTES) as client:
            store = client.app.state.store
            post = poster(client)
            outcomes = Outcomes()
            for _ in range(5):
                assert outcomes.send(post) == 200
            filler = fill(disk, leave=LEAVE_BYTES)

            report = break_store(post, outcomes)
            assert "invalidated" in report["output"], report
            # The commit whose checkpoint failed is durable: it was acknowledged.
            assert outcomes.next_seq - 1 in outcomes.acked
            # The ingest log, on the same disk, may still have room (the slack of its
            # last page): acknowledged there, applied after the reopen. Take the rest.
            rest = fill(disk, leave=0, name="rest")

            # Broken: reads answer 503; writes too once the log is full, and a refused
            # write says it stored nothing.
            status, body = post("GET", f"/v2/entities/{ENTITY}/attrs/seq", None)
            assert status == 503 and body["error"] == "ServiceUnavailable", body
            assert any(outcomes.send(post) == 503 for _ in range(50))
            assert "nothing was stored" in outcomes.bodies[-1]["description"]

            filler.unlink()
            rest.unlink()
            wait_healthy(post, outcomes)
            assert store.reopens >= 1
            for _ in range(100):  # more than one checkpoint's worth: the file takes them again
                assert outcomes.send(post) == 200
            check_exactly_once(outcomes, stored_seqs(post))
            assert outcomes.statuses.keys() <= {200, 503}

        # And the file holds exactly that after a clean close and a fresh open.
        with client_factory(str(disk / "tsdb.duckdb")) as client:
            check_exactly_once(outcomes, stored_seqs(poster(client)))


@pytest.fixture
def quick_reopen(monkeypatch):
    monkeypatch.setattr(duckdb_store, "REOPEN_DELAY_S", 0.05)
    monkeypatch.setattr(duckdb_store, "REOPEN_MAX_DELAY_S", 0.2)


def test_a_disk_that_stays_full_is_retried_until_space_is_back(tmp_path, client_factory, quick_reopen):
    """Reopening works on a full disk (DuckDB replays the WAL in memory), and
    the next checkpoint fails again: the store goes round that loop, never
    losing or duplicating a write, until there is space."""
    with (
        small_tmpfs(tmp_path / "disk", "24m") as disk,
        client_factory(str(disk / "tsdb.duckdb"), wal_checkpoint_bytes=CHECKPOINT_BYTES) as client,
    ):
        store = client.app.state.store
        post = poster(client)
        outcomes = Outcomes()
        filler = fill(disk, leave=LEAVE_BYTES)
        break_store(post, outcomes)
        deadline = time.monotonic() + 3.0
        while time.monotonic() < deadline:
            outcomes.send(post)
            status, body = post("GET", f"/v2/entities/{ENTITY}/attrs/seq?lastN=5", None)
            assert status in (200, 503), body
        filler.unlink()
        wait_healthy(post, outcomes)
        for _ in range(100):
            assert outcomes.send(post) == 200
        check_exactly_once(outcomes, stored_seqs(post))
        assert store.reopens >= 1, store.reopens
