"""A damaged ingest log is never replayed past the damage, never silently,
and never into another database (DuckDB, through real server processes).

Each test leaves records acknowledged and not applied in a store's log (as
a crash does), damages the log as a disk or an operator might, and starts
the service on it: what precedes the damage is applied; the damaged record
and everything after it is set aside in ``FILE.ingest-log/quarantine/``,
said in one log line, counted on ``/metrics``, and ``/health`` warns until
an operator takes the quarantine folder away. A torn last record (a crash
during a write, never acknowledged) is not damage: it is cut without a word.
"""

from __future__ import annotations

import re
import shutil

import httpx
import pytest

from tests.support.ingest_log import leave_unapplied, log_dir, readings, segments
from tests.support.server import ServerError, ServerProcess

TENANT = "damaged"
HEADERS = {"Fiware-Service": TENANT, "Fiware-ServicePath": "/"}
RECORDS = 20
SMALL_SEGMENTS = 1024  # about three records a segment


def levels(client: httpx.Client, entity_id: str = "Tank:1") -> list[float]:
    answer = client.get(f"/v2/entities/{entity_id}/attrs/level", params={"limit": 1000}, headers=HEADERS)
    if answer.status_code == 404:
        return []
    assert answer.status_code == 200, answer.text
    body = answer.json()
    return [] if body == [] else body["values"]  # [] : nothing stored for the tenant


def expected(values: range) -> list[float]:
    return [v + 0.25 for v in values]


def metric(client: httpx.Client, name: str) -> float:
    text = client.get("/metrics").text
    found = re.search(rf"^{name}(?:_total)? (\S+)$", text, re.M)
    assert found, f"{name} not on /metrics"
    return float(found.group(1))


def flip_byte_of(db_path, value: int) -> str:
    """Change one byte in the record carrying ``value``; the segment's name."""
    needle = f",{value + 0.25},".encode()  # the sample's num, in the record's array (write.codec)
    for segment in segments(db_path):
        data = bytearray(segment.read_bytes())
        at = data.find(needle)
        if at >= 0:
            data[at + len(needle) - 2] ^= 0x01  # 5.25 -> 5.24: the checksum no longer matches
            segment.write_bytes(bytes(data))
            return segment.name
    raise AssertionError(f"no record carries {value}")


def leave_records(db_path, segment_bytes: int | None = None) -> None:
    leave_unapplied(db_path, [readings(TENANT, "Tank:1", [v]) for v in range(RECORDS)], segment_bytes=segment_bytes)


def quarantined(db_path) -> list:
    folder = log_dir(db_path) / "quarantine"
    return sorted(p for p in folder.rglob("*") if p.is_file()) if folder.exists() else []


def check_set_aside(server: ServerProcess, client: httpx.Client, db_path, segment: str, records: int) -> None:
    """One log line names the segment and how much was set aside; the
    quarantine holds it; /metrics counts it; /health warns until the
    quarantine folder is taken away, then passes again."""
    lines = [line for line in server.output().splitlines() if "ingest log" in line and "set aside" in line]
    assert len(lines) == 1, server.output()[-3000:]
    assert segment in lines[0] and "offset" in lines[0], lines[0]
    assert f"{records} records" in lines[0], lines[0]
    assert quarantined(db_path), "nothing in the quarantine folder"
    assert metric(client, "tsdb_ingest_log_set_aside_records") == records
    assert metric(client, "tsdb_ingest_log_set_aside_bytes") > 0
    health = client.get("/health")
    assert health.status_code == 200 and health.json()["status"] == "warn", health.text
    assert "quarantine" in health.json()["output"], health.text
    shutil.rmtree(log_dir(db_path) / "quarantine")  # the operator has looked: acknowledged
    health = client.get("/health")
    assert health.json()["status"] == "pass", health.text


def test_a_flipped_byte_in_the_last_segment_stops_the_replay_there_and_says_so(tmp_path):
    db = tmp_path / "last.duckdb"
    leave_records(db)
    segment = flip_byte_of(db, 5)
    with ServerProcess(db) as server, httpx.Client(base_url=server.url, timeout=10) as client:
        assert levels(client) == expected(range(5))  # nothing after the damage, nothing altered
        check_set_aside(server, client, db, segment, records=RECORDS - 5)
    with ServerProcess(db) as server, httpx.Client(base_url=server.url, timeout=10) as client:
        assert levels(client) == expected(range(5))
        assert "set aside" not in server.output()  # said once, at the start that found it
        assert client.get("/health").json()["status"] == "pass"


def test_a_flipped_byte_in_an_older_segment_sets_aside_the_rest_of_the_log(tmp_path):
    db = tmp_path / "older.duckdb"
    leave_records(db, SMALL_SEGMENTS)
    assert len(segments(db)) > 3
    segment = flip_byte_of(db, 4)
    assert segment != segments(db)[-1].name
    with ServerProcess(db) as server, httpx.Client(base_url=server.url, timeout=10) as client:
        assert levels(client) == expected(range(4))
        check_set_aside(server, client, db, segment, records=RECORDS - 4)


def test_an_emptied_last_segment_is_said_and_set_aside(tmp_path):
    db = tmp_path / "emptied.duckdb"
    leave_records(db, SMALL_SEGMENTS)
    last = segments(db)[-1]
    kept = len(segments(db)[-2].read_bytes())  # just to be sure there are records before it
    assert kept > 0
    last.write_bytes(b"")
    with ServerProcess(db) as server, httpx.Client(base_url=server.url, timeout=10) as client:
        before = levels(client)
        assert before == expected(range(len(before))) and 0 < len(before) < RECORDS
        lines = [line for line in server.output().splitlines() if last.name in line]
        assert lines and "empty" in lines[0], server.output()[-3000:]
        assert quarantined(db)
        assert client.get("/health").json()["status"] == "warn"


def test_a_stray_empty_segment_past_the_end_never_makes_reads_hang(tmp_path):
    db = tmp_path / "stray.duckdb"
    leave_records(db)
    (log_dir(db) / f"{10**17:018d}.seg").write_bytes(b"")
    (log_dir(db) / "notes.txt").write_text("an operator's file")
    with ServerProcess(db) as server, httpx.Client(base_url=server.url, timeout=10) as client:
        assert levels(client) == expected(range(RECORDS))  # a hang is a ReadTimeout here
        answer = client.post(
            "/v2/notify",
            json={
                "subscriptionId": "5f0000000000000000000000",
                "data": [{"id": "Tank:1", "type": "Tank", "level": {"type": "Number", "value": 99.25}}],
            },
            headers=HEADERS,
        )
        assert answer.status_code == 200, answer.text
        assert levels(client)[-1] == 99.25
        output = server.output()
        assert f"{10**17:018d}.seg" in output and "notes.txt" in output, output[-3000:]
    assert (log_dir(db) / "notes.txt").exists()  # never deleted: only said


def test_another_databases_log_is_refused_never_replayed(tmp_path):
    mine, theirs = tmp_path / "mine.duckdb", tmp_path / "theirs.duckdb"
    leave_records(theirs)
    leave_unapplied(mine, [])
    shutil.rmtree(log_dir(mine))
    shutil.copytree(log_dir(theirs), log_dir(mine))
    before = {p.name: p.read_bytes() for p in segments(mine)}
    server = ServerProcess(mine, startup_timeout=20)
    with pytest.raises(ServerError) as refused:
        server.start()
    output = str(refused.value)
    assert "another database" in output and str(log_dir(mine)) in output, output
    assert {p.name: p.read_bytes() for p in segments(mine)} == before  # untouched
    shutil.rmtree(log_dir(mine))  # the operator moves it away: the store starts, without their samples
    with ServerProcess(mine) as server, httpx.Client(base_url=server.url, timeout=10) as client:
        assert levels(client) == []
    with ServerProcess(theirs) as server, httpx.Client(base_url=server.url, timeout=10) as client:
        assert levels(client) == expected(range(RECORDS))  # their own log is theirs


def test_a_torn_last_record_is_cut_without_a_word(tmp_path):
    db = tmp_path / "torn.duckdb"
    leave_records(db)
    last = segments(db)[-1]
    data = last.read_bytes()
    last.write_bytes(data[: len(data) - 7])  # a crash before the last write's fdatasync returned
    with ServerProcess(db) as server, httpx.Client(base_url=server.url, timeout=10) as client:
        assert levels(client) == expected(range(RECORDS - 1))
        assert client.get("/health").json()["status"] == "pass"
        assert "set aside" not in server.output() and not quarantined(db)
