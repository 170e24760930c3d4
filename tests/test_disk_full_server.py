"""Disk full under load, through a real server process (DuckDB).

Four clients keep posting notifications while the disk the DuckDB file lives
on fills up, a checkpoint fails and the database is invalidated; then space
comes back. The server must never answer 500, ``/health`` must go from pass
to fail and back to pass without a restart, and every acknowledged
notification must be stored exactly once.
"""

from __future__ import annotations

import http.client
import json
import threading
import time

from tests.support.disk_full import (
    HEADERS,
    READ_HEADERS,
    Outcomes,
    check_exactly_once,
    stored_seqs,
)
from tests.support.server import ServerProcess
from tests.support.tmpfs import fill, small_tmpfs

CLIENTS = 4
LEAVE_BYTES = 160 * 1024
FAIL_TIMEOUT_S = 60.0
RECOVER_TIMEOUT_S = 30.0


class Http:
    """One keep-alive connection per thread; ``post`` as the scenario wants it."""

    def __init__(self, port: int):
        self.port = port
        self.local = threading.local()

    def __call__(self, method: str, path: str, body: bytes | None):
        conn = getattr(self.local, "conn", None)
        if conn is None:
            conn = self.local.conn = http.client.HTTPConnection("127.0.0.1", self.port, timeout=30)
        conn.request(method, path, body=body, headers=HEADERS if method == "POST" else READ_HEADERS)
        response = conn.getresponse()
        data = response.read()
        assert response.status != 500, data
        return response.status, json.loads(data or b"{}")


def load(post: Http, outcomes: Outcomes, stop: threading.Event, errors: list) -> None:
    try:
        while not stop.is_set():
            outcomes.send(post)
    except BaseException as exc:  # surfaced by the test
        errors.append(exc)


def wait_health(post: Http, want: str, timeout: float, errors: list) -> list[str]:
    """Poll /health until its status is ``want``; return every status seen."""
    seen = []
    deadline = time.monotonic() + timeout
    while not errors:
        status, report = post("GET", "/health", None)
        assert (status, report["status"]) in ((200, "pass"), (503, "fail")), (status, report)
        seen.append(report["status"])
        if report["status"] == want:
            return seen
        assert time.monotonic() < deadline, f"/health not {want} after {timeout} s: {report}"
        time.sleep(0.05)
    raise errors[0]


def test_disk_full_under_load_recovers_without_restart(tmp_path):
    with small_tmpfs(tmp_path / "disk", "24m") as disk:
        env = {"TSDB_WAL_CHECKPOINT_BYTES": str(64 * 1024)}
        with ServerProcess(disk / "tsdb.duckdb", extra_env=env, log_dir=tmp_path) as server:
            post = Http(server.port)
            outcomes = Outcomes()
            for _ in range(5):
                assert outcomes.send(post) == 200
            filler = fill(disk, leave=LEAVE_BYTES)
            stop, errors = threading.Event(), []
            clients = [
                threading.Thread(target=load, args=(Http(server.port), outcomes, stop, errors)) for _ in range(CLIENTS)
            ]
            for thread in clients:
                thread.start()
            try:
                wait_health(post, "fail", FAIL_TIMEOUT_S, errors)
                time.sleep(0.5)  # keep posting against the broken store
                filler.unlink()
                wait_health(post, "pass", RECOVER_TIMEOUT_S, errors)
                time.sleep(1.0)  # and against the reopened one
            finally:
                stop.set()
                for thread in clients:
                    thread.join()
            assert not errors, errors[0]
            for _ in range(20):  # after recovery every notification is stored
                assert outcomes.send(post) == 200
            check_exactly_once(outcomes, stored_seqs(post))
            assert "reopened" in server.output()
            assert outcomes.statuses[503] > 0, outcomes.statuses
