"""``serve --ingest-processes 2``: an acceptor process shares the port with
the serving process and relays what it parses (``ingest.relay``).

Through real servers: each request on a connection of its own, so the
kernel spreads them over both processes. Every notification acknowledged is
stored once and readable at once whichever process took it; refusals are
kept; a ``values`` layout registered a moment ago is used; every other
request is answered by the owner unchanged; an acceptor killed is started
again and loses nothing; the owner killed takes its acceptors with it and a
restart stores every acknowledged notification once.
"""

from __future__ import annotations

import http.client
import os
import re
import signal
import subprocess
import sys
import threading
import time
import urllib.request
from pathlib import Path

import duckdb
import orjson
import pytest

from tests.support.crash_load import ACK, KILL_AFTER_ACKS, TENANT, client, entity_id, temperature, wait_for_acks
from tests.support.server import ServerProcess

ARGS = ["--ingest-processes", "2"]
HEADERS = {"Content-Type": "application/json", "Fiware-Service": "relay", "Fiware-ServicePath": "/"}


def _wait(condition, timeout: float = 60.0, what: str = "condition") -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(0.05)


def _ready(server: ServerProcess) -> ServerProcess:
    """Both processes serve: the acceptor has finished starting."""
    _wait(lambda: server.output().count("Application startup complete.") >= 2, what="the acceptor to start")
    return server


def _metric(server: ServerProcess, name: str) -> float:
    with urllib.request.urlopen(server.url + "/metrics", timeout=10) as answer:
        text = answer.read().decode()
    found = re.search(rf"^{name}(?:_total)? (\S+)$", text, re.M)
    assert found, f"{name} not in /metrics"
    return float(found.group(1))


def _notify_answers(server: ServerProcess) -> float:
    with urllib.request.urlopen(server.url + "/metrics", timeout=10) as answer:
        text = answer.read().decode()
    pattern = r'^tsdb_http_request_duration_seconds_count\{method="POST",route="/v2/notify",status="200"\} (\S+)$'
    found = re.search(pattern, text, re.M)
    return float(found.group(1)) if found else 0.0


def _once(port: int, method: str, path: str, body: bytes | None = None, headers: dict | None = None):
    """One request on a connection of its own: (status, headers, body)."""
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=30)
    try:
        conn.request(method, path, body=body, headers=headers or {})
        response = conn.getresponse()
        return response.status, dict(response.getheaders()), response.read()
    finally:
        conn.close()


def _notification(n: int, entity: str | None = None) -> bytes:
    return orjson.dumps(
        {
            "subscriptionId": "s1",
            "data": [
                {
                    "id": entity or f"urn:ngsi-ld:Relay:{n}",
                    "type": "Relay",
                    "level": {"type": "Number", "value": n + 0.5},
                    "TimeInstant": {"type": "DateTime", "value": f"2024-05-01T10:{n // 60 % 60:02d}:{n % 60:02d}Z"},
                }
            ],
        }
    )


def _stored(db_path, tenant: str, attr: str) -> list[tuple[str, float]]:
    con = duckdb.connect(str(db_path), read_only=True)
    try:
        return con.execute(
            "SELECT s.entity_id, a.num FROM series s JOIN samples_all a ON a.sid = s.sid "
            "WHERE s.tenant = ? AND s.attr = ?",
            [tenant, attr],
        ).fetchall()
    finally:
        con.close()


@pytest.fixture
def served(tmp_path):
    db_path = tmp_path / "relay.duckdb"
    server = _ready(ServerProcess(db_path, args=ARGS).start())
    try:
        yield server, db_path
    finally:
        if server.running():
            server.terminate()


def test_every_notification_is_stored_once_and_read_at_once_whichever_process_took_it(served):
    server, db_path = served
    assert len(server.children()) == 1
    errors: list[str] = []

    def send(first: int) -> None:
        for n in range(first, first + 60):
            status, _, body = _once(server.port, "POST", "/v2/notify", _notification(n), HEADERS)
            if status != 200:
                errors.append(f"{n}: {status} {body[:200]!r}")
                continue
            path = f"/v2/entities/urn:ngsi-ld:Relay:{n}/attrs/level?lastN=1"
            status, _, body = _once(server.port, "GET", path, headers=HEADERS)
            if status != 200 or orjson.loads(body)["values"] != [n + 0.5]:
                errors.append(f"{n}: read back {status} {body[:200]!r}")

    threads = [threading.Thread(target=send, args=(i * 1000,)) for i in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors, errors[:5]
    relayed = _metric(server, "tsdb_ingest_relayed_writes")
    assert relayed > 0, "the acceptor took none of 240 connections"
    # Every answer is in the owner's /metrics, whichever process gave it (the acceptor's within a second).
    _wait(lambda: _notify_answers(server) == 240, 10, "the acceptor's answers in /metrics")
    assert _metric(server, "tsdb_ingest_processes_running") == 1
    server.terminate()
    rows = _stored(db_path, "relay", "level")
    assert sorted(rows) == sorted(
        (f"urn:ngsi-ld:Relay:{n}", n + 0.5) for i in range(4) for n in range(i * 1000, i * 1000 + 60)
    )


def test_a_refused_notification_gets_the_same_answer_and_is_kept(served):
    server, _ = served
    answers = {_once(server.port, "POST", "/v2/notify", b'{"data": 5}', HEADERS)[::2] for _ in range(40)}
    assert answers == {
        (400, b'{"error":"ParseError","description":"notification \'data\' must be an array, got a number"}')
    }
    status, _, _ = _once(server.port, "POST", "/v2/notify", b"x=1", {**HEADERS, "Content-Type": "text/plain"})
    assert status == 415
    assert _metric(server, "tsdb_ingest_relayed_writes") > 0
    status, _, body = _once(server.port, "GET", "/v2/notify/rejected?limit=100", headers=HEADERS)
    kept = orjson.loads(body)
    assert status == 200 and len(kept) == 41
    assert {k["error"] for k in kept} == {"ParseError", "UnsupportedMediaType"}


def test_a_values_layout_registered_a_moment_ago_is_used(served):
    server, db_path = served
    for version, attrs in enumerate((["id", "level"], ["level", "id"])):
        layout = orjson.dumps({"attrs": attrs, "entityType": "Relay"})
        status, _, _ = _once(server.port, "PUT", "/v2/notify/subscriptions/sv", layout, HEADERS)
        assert status == 200
        for n in range(20):
            row = [f"urn:v:{version}:{n}", float(n)] if attrs[0] == "id" else [float(n), f"urn:v:{version}:{n}"]
            body = orjson.dumps({"subscriptionId": "sv", "data": [row]})
            status, _, answer = _once(
                server.port, "POST", "/v2/notify", body, {**HEADERS, "Ngsiv2-AttrsFormat": "values"}
            )
            assert status == 200, answer
    server.terminate()
    rows = sorted(_stored(db_path, "relay", "level"))
    assert rows == sorted((f"urn:v:{v}:{n}", float(n)) for v in range(2) for n in range(20))


def test_every_other_request_is_answered_by_the_owner_unchanged(served):
    server, _ = served
    for n in range(3):
        assert _once(server.port, "POST", "/v2/notify", _notification(n, "urn:a/b"), HEADERS)[0] == 200
    paths = ["/version", "/v2/entities/urn:a%2Fb/attrs/level?lastN=2", "/v2/entities?limit=5", "/nope"]
    for path in paths:
        answers = {(s, b) for s, _, b in (_once(server.port, "GET", path, headers=HEADERS) for _ in range(24))}
        assert len(answers) == 1, (path, answers)
    heads = {
        (s, b) for s, _, b in (_once(server.port, "HEAD", "/v2/notify/rejected", headers=HEADERS) for _ in range(12))
    }
    assert len(heads) == 1 and heads.pop()[1] == b""
    # A large answer streams through whole (the explorer's page: well over one read of the socket).
    sizes = {len(_once(server.port, "GET", "/ui/")[2]) for _ in range(12)}
    assert len(sizes) == 1 and sizes.pop() > 1000


def test_notifications_need_the_same_credentials_in_every_process(tmp_path):
    env = {"TSDB_API_KEYS": "writer-key-0123456789:write;reader-key-0123456789:read"}
    server = _ready(ServerProcess(tmp_path / "auth.duckdb", extra_env=env, args=ARGS).start())
    try:
        missing = {_once(server.port, "POST", "/v2/notify", _notification(1), HEADERS)[0] for _ in range(24)}
        reader = {**HEADERS, "X-Api-Key": "reader-key-0123456789"}
        wrong = {_once(server.port, "POST", "/v2/notify", _notification(1), reader)[0] for _ in range(24)}
        writer = {**HEADERS, "X-Api-Key": "writer-key-0123456789"}
        right = {_once(server.port, "POST", "/v2/notify", _notification(1), writer)[0] for _ in range(24)}
        assert (missing, wrong, right) == ({401}, {403}, {200})
        assert _metric_with_key(server, "tsdb_ingest_relayed_writes", "reader-key-0123456789") > 0
    finally:
        server.terminate()


def _metric_with_key(server: ServerProcess, name: str, key: str) -> float:
    request = urllib.request.Request(server.url + "/metrics", headers={"X-Api-Key": key})
    with urllib.request.urlopen(request, timeout=10) as answer:
        text = answer.read().decode()
    return float(re.search(rf"^{name}(?:_total)? (\S+)$", text, re.M).group(1))


def _drive(port: int, outcomes: dict[int, str], stop: threading.Event, seqs) -> list[threading.Thread]:
    threads = [threading.Thread(target=client, args=(port, seqs, outcomes, stop), daemon=True) for _ in range(8)]
    for t in threads:
        t.start()
    return threads


def _acked_stored_once(db_path, outcomes: dict[int, str]) -> None:
    stored = _stored(db_path, TENANT, "temperature")
    counts: dict[tuple[str, float], int] = {}
    for row in stored:
        counts[row] = counts.get(row, 0) + 1
    doubled = [row for row, c in counts.items() if c > 1]
    acked = [s for s, o in outcomes.items() if o == ACK]
    lost = [s for s in acked if (entity_id(s), temperature(s)) not in counts]
    assert not doubled, f"stored twice: {doubled[:5]}"
    assert not lost, f"acknowledged and lost: {[entity_id(s) for s in lost[:5]]} of {len(acked)}"
    assert len(acked) >= KILL_AFTER_ACKS


def test_a_killed_acceptor_is_started_again_and_loses_nothing(tmp_path):
    import itertools

    db_path = tmp_path / "acceptor-kill.duckdb"
    server = _ready(ServerProcess(db_path, args=ARGS).start())
    outcomes: dict[int, str] = {}
    stop = threading.Event()
    threads = _drive(server.port, outcomes, stop, itertools.count())
    try:
        wait_for_acks(outcomes, KILL_AFTER_ACKS, 120)
        (acceptor,) = server.children()
        os.kill(acceptor, signal.SIGKILL)
        _wait(lambda: server.children() and server.children() != [acceptor], what="the acceptor to start again")
        _wait(lambda: _metric(server, "tsdb_ingest_process_restarts") == 1, what="the restart to be counted")
        acked = sum(1 for o in list(outcomes.values()) if o == ACK)
        wait_for_acks(outcomes, acked + 200, 120)  # and the service goes on taking notifications
    finally:
        stop.set()
        for t in threads:
            t.join(15)
    assert "ingest process 1 (pid" in server.output() and "exited with status -9" in server.output()
    server.terminate()
    _acked_stored_once(db_path, outcomes)


def test_the_owner_killed_takes_its_acceptor_along_and_a_restart_keeps_every_acknowledged_notification(tmp_path):
    import itertools

    db_path = tmp_path / "owner-kill.duckdb"
    server = _ready(ServerProcess(db_path, args=ARGS).start())
    (acceptor,) = server.children()
    environ = Path(f"/proc/{acceptor}/environ").read_bytes().split(b"\0")  # as the owner made it
    relay_dir = next(v.split(b"=", 1)[1].decode() for v in environ if v.startswith(b"TSDB_INTERNAL_RELAY_DIR="))
    outcomes: dict[int, str] = {}
    stop = threading.Event()
    seqs = itertools.count()
    threads = _drive(server.port, outcomes, stop, seqs)
    try:
        wait_for_acks(outcomes, KILL_AFTER_ACKS, 120)
        os.kill(server.pid, signal.SIGKILL)  # the owner alone: its acceptor must notice
        server.proc.wait()
        _wait(lambda: not os.path.exists(f"/proc/{acceptor}") or _zombie(acceptor), 15, "the acceptor to stop")
        time.sleep(0.3)
    finally:
        stop.set()
        for t in threads:
            t.join(15)
    _wait(lambda: not os.path.exists(relay_dir), 10, "the killed run's directory to go")
    again = ServerProcess(db_path, args=ARGS).start()
    again.terminate()
    _acked_stored_once(db_path, outcomes)


def _zombie(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as stat:
            return stat.read().split(")")[-1].split()[0] == "Z"
    except OSError:
        return True


def test_ingest_processes_are_refused_with_postgresql(tmp_path):
    done = subprocess.run(
        [sys.executable, "-m", "tsdb_service", "serve", "--db", "postgresql://localhost/x", "--ingest-processes", "2"],
        capture_output=True,
        text=True,
        timeout=60,
        env={k: v for k, v in os.environ.items() if not k.startswith("TSDB_")},
    )
    assert done.returncode == 2
    assert done.stderr.strip().splitlines() == [
        "error: --ingest-processes > 1 is for DuckDB, whose file belongs to one process; with PostgreSQL use "
        "--workers, whose processes each write to the database."
    ]


def test_a_connection_that_reads_is_handed_to_the_owner_and_stays_there(served):
    """Keep-alive connections spread over both processes; each asks a read
    once, then the acceptor is stopped (SIGSTOP): every connection still
    answers, so none of them is left with the acceptor, or passes through it."""
    server, _ = served
    assert _once(server.port, "POST", "/v2/notify", _notification(1, "urn:keep"), HEADERS)[0] == 200
    path = "/v2/entities/urn:keep/attrs/level?lastN=1"
    connections = [http.client.HTTPConnection("127.0.0.1", server.port, timeout=5) for _ in range(16)]
    (acceptor,) = server.children()
    try:
        first = []
        for conn in connections:
            conn.request("GET", path, headers=HEADERS)
            response = conn.getresponse()
            first.append((response.status, response.read()))
        os.kill(acceptor, signal.SIGSTOP)
        try:
            again = []
            for conn in connections:
                for _ in range(3):
                    conn.request("GET", path, headers=HEADERS)
                    response = conn.getresponse()
                    again.append((response.status, response.read()))
        finally:
            os.kill(acceptor, signal.SIGCONT)
    finally:
        for conn in connections:
            conn.close()
    assert len(set(first)) == 1 and first[0][0] == 200
    assert set(again) == set(first)
