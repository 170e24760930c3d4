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

import http.client
import itertools
import json
import signal
import threading
import time

import duckdb

from tests.support.server import ServerProcess

TENANT = "crashtest"
THREADS = 16
KILL_AFTER_ACKS = 300  # acknowledged notifications before the kill: enough load to mean something
ACK_TIMEOUT_S = 120.0  # generous: a busy machine is slow, not wrong
AFTER_KILL_S = 0.5  # the clients keep sending into the dead server (refused, reset)

ACK = "ack"  # 2xx: the server promised the samples are committed
REFUSED = "refused"  # connection refused: the request never left the client
FAILED = "failed"  # sent (maybe partly), then reset/closed: outcome unknown
REJECTED = "rejected"  # a non-2xx answer

HEADERS = {
    "Content-Type": "application/json",
    "Fiware-Service": TENANT,
    "Fiware-ServicePath": "/",
    "Ngsiv2-AttrsFormat": "normalized",
}


def entity_id(seq: int) -> str:
    return f"urn:ngsi-ld:Crash:{seq}"


def temperature(seq: int) -> float:
    return seq + 0.5  # exact in a double


def notification(seq: int) -> bytes:
    ms = seq % 1000
    secs = seq // 1000
    stamp = f"2024-05-01T10:{secs // 60 % 60:02d}:{secs % 60:02d}.{ms:03d}Z"
    entity = {
        "id": entity_id(seq),
        "type": "CrashSensor",
        "temperature": {"type": "Number", "value": temperature(seq), "metadata": {}},
        "TimeInstant": {"type": "DateTime", "value": stamp, "metadata": {}},
    }
    return json.dumps({"subscriptionId": "5f0000000000000000c0ffee", "data": [entity]}).encode()


def client(port: int, seqs: itertools.count, outcomes: dict[int, str], stop: threading.Event) -> None:
    """One keep-alive connection, one request at a time, until stopped."""
    conn: http.client.HTTPConnection | None = None
    while not stop.is_set():
        seq = next(seqs)
        if conn is None:
            conn = http.client.HTTPConnection("127.0.0.1", port, timeout=10)
        try:
            conn.request("POST", "/v2/notify", body=notification(seq), headers=HEADERS)
            resp = conn.getresponse()
            resp.read()
            outcomes[seq] = ACK if 200 <= resp.status < 300 else REJECTED
        except ConnectionRefusedError:
            outcomes[seq] = REFUSED
            conn.close()
            conn = None
            time.sleep(0.02)
        except (OSError, http.client.HTTPException):
            outcomes[seq] = FAILED
            conn.close()
            conn = None
    if conn is not None:
        conn.close()


def acknowledged(outcomes: dict[int, str]) -> int:
    return sum(1 for o in list(outcomes.values()) if o == ACK)


def wait_for_acks(outcomes: dict[int, str], count: int, timeout: float) -> int:
    """Block until ``count`` notifications are acknowledged; fail after ``timeout`` s."""
    deadline = time.monotonic() + timeout
    while (acked := acknowledged(outcomes)) < count:
        assert time.monotonic() < deadline, f"only {acked} of {count} notifications acknowledged in {timeout:g} s"
        time.sleep(0.01)
    return acked


def drive_then_kill(servers: list[ServerProcess], outcomes: dict[int, str]) -> tuple[list, int]:
    """Clients spread over ``servers``; every server is SIGKILLed once
    KILL_AFTER_ACKS notifications are acknowledged, the clients stop
    AFTER_KILL_S later. Returns the kill exit codes and how many
    notifications were acknowledged before the kill."""
    seqs = itertools.count()
    stop = threading.Event()
    threads = [
        threading.Thread(
            target=client, args=(servers[i % len(servers)].port, seqs, outcomes, stop), name=f"client-{i}", daemon=True
        )
        for i in range(THREADS)
    ]
    try:
        for t in threads:
            t.start()
        acked_before_kill = wait_for_acks(outcomes, KILL_AFTER_ACKS, ACK_TIMEOUT_S)
        codes = [server.kill() for server in servers]
        time.sleep(AFTER_KILL_S)
    finally:
        stop.set()
        for t in threads:
            t.join(15)
        for server in servers:
            server.kill()
    assert not any(t.is_alive() for t in threads), "client threads did not stop"
    return codes, acked_before_kill


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
