"""The load the crash tests kill a server under (both backends).

16 clients (``THREADS``) send notifications, each a unique entity id and
value, and record every outcome: ``ACK`` (2xx: the server promised the
samples are durable), ``REFUSED`` (never left the client), ``FAILED`` (sent,
then reset: outcome unknown), ``REJECTED`` (a non-2xx answer).
``drive_then_kill`` SIGKILLs the server once ``KILL_AFTER_ACKS`` are
acknowledged, whatever the machine's speed, while the clients go on sending.
"""

from __future__ import annotations

import http.client
import itertools
import json
import threading
import time

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
