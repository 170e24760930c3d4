"""``/health`` fails while the ingest log cannot be written, and passes
again once it can (DuckDB, through a real server process, the log's
directory on a small tmpfs of its own).

Every notification gets a 503 ("nothing was stored") while the log's disk
is full or its directory is read-only: a probe on ``/health`` must see the
same, with the reason, and ``/metrics`` counts the failed writes.
"""

from __future__ import annotations

import contextlib
import re
import subprocess
from collections.abc import Iterator
from pathlib import Path

import httpx

from tests.support.ingest_log import log_dir
from tests.support.server import ServerProcess
from tests.support.tmpfs import fill, small_tmpfs

TENANT = "logdisk"
HEADERS = {"Fiware-Service": TENANT, "Fiware-ServicePath": "/"}
PAD = "p" * 2000


def notify(client: httpx.Client, n: int) -> httpx.Response:
    entity = {
        "id": "Disk:1",
        "type": "Disk",
        "n": {"type": "Number", "value": n},
        "pad": {"type": "Text", "value": PAD},
    }
    return client.post(
        "/v2/notify", json={"subscriptionId": "5f000000000000000000d15c", "data": [entity]}, headers=HEADERS
    )


def stored(client: httpx.Client) -> list[int]:
    answer = client.get("/v2/entities/Disk:1/attrs/n", params={"limit": 10000}, headers=HEADERS)
    assert answer.status_code == 200, answer.text
    return [int(v) for v in answer.json()["values"]]


def health(client: httpx.Client) -> tuple[int, dict]:
    answer = client.get("/health")
    return answer.status_code, answer.json()


def failures(client: httpx.Client) -> float:
    found = re.search(r"^tsdb_ingest_log_write_failures_total (\S+)$", client.get("/metrics").text, re.M)
    assert found, "tsdb_ingest_log_write_failures_total not on /metrics"
    return float(found.group(1))


@contextlib.contextmanager
def served_with_its_log_on_a_tmpfs(tmp_path) -> Iterator[tuple[Path, httpx.Client]]:
    """A server whose database is on the test's disk and whose ingest log
    has a small tmpfs of its own (the disk, a client of the server)."""
    db = tmp_path / "store.duckdb"
    with (
        small_tmpfs(log_dir(db), "2m") as disk,
        ServerProcess(db, log_dir=tmp_path) as server,
        httpx.Client(base_url=server.url, timeout=30) as client,
    ):
        yield disk, client


def test_health_fails_while_the_log_disk_is_full_and_recovers(tmp_path):
    with served_with_its_log_on_a_tmpfs(tmp_path) as (disk, client):
        acked = [n for n in range(3) if notify(client, n).status_code == 200]
        assert acked == [0, 1, 2]
        filler = fill(disk, leave=0)
        refused = []
        for n in range(3, 200):  # the segment's last page may still take a few
            answer = notify(client, n)
            if answer.status_code == 200:
                acked.append(n)
                continue
            assert answer.status_code == 503, answer.text
            assert "nothing was stored" in answer.json()["description"], answer.text
            refused.append(n)
            break
        assert refused, "the full disk never refused a write"
        status, report = health(client)
        assert status == 503 and report["status"] == "fail", report
        assert "ingest log" in report["output"], report
        assert failures(client) >= 1
        filler.unlink()
        assert notify(client, 500).status_code == 200
        acked.append(500)
        status, report = health(client)
        assert (status, report["status"]) == (200, "pass"), report
        assert stored(client) == acked


def test_health_fails_while_the_log_directory_is_read_only_and_recovers(tmp_path):
    with served_with_its_log_on_a_tmpfs(tmp_path) as (disk, client):
        assert health(client)[1]["status"] == "pass"
        subprocess.run(["mount", "-o", "remount,ro", str(disk)], check=True)
        try:
            status, report = health(client)  # before any write fails: the probe sees it
            assert status == 503 and report["status"] == "fail", report
            assert "not writable" in report["output"], report
            answer = notify(client, 1)
            assert answer.status_code == 503 and "nothing was stored" in answer.json()["description"]
            assert health(client)[0] == 503
        finally:
            subprocess.run(["mount", "-o", "remount,rw", str(disk)], check=True)
        assert notify(client, 2).status_code == 200
        status, report = health(client)
        assert (status, report["status"]) == (200, "pass"), report
        assert stored(client) == [2]
