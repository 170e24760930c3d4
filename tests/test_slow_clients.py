"""Slow and idle clients cannot exhaust the server (a real server process).

Half-open requests (headers never finished, bodies never finished) are
closed after ``TSDB_HEADER_TIMEOUT_S`` / ``TSDB_BODY_TIMEOUT_S`` while normal
requests keep being answered; past ``TSDB_MAX_CONNECTIONS`` a new connection
gets 503 and is closed; a client that sends half a body and disconnects is
one log line, not a traceback. Sockets are few (hundreds) and on 127.0.0.1.
"""

from __future__ import annotations

import select
import socket
import time

import httpx
import pytest

from tests.support.server import ServerProcess

HALF_OPEN = 300
TIMEOUT_S = 1.0
NOTIFICATION = b'{"subscriptionId":"s","data":[{"id":"E","type":"T","v":{"type":"Number","value":1}}]}'


def _connect(port: int, payload: bytes) -> socket.socket:
    sock = socket.create_connection(("127.0.0.1", port), timeout=5)
    sock.sendall(payload)
    return sock


def _closed_by_peer(sock: socket.socket, wait: float) -> bool:
    """True when the server closed (EOF or reset) within ``wait`` seconds."""
    ready, _, _ = select.select([sock], [], [], wait)
    if not ready:
        return False
    try:
        return sock.recv(4096) == b""  # uvicorn closes without answering
    except ConnectionResetError:
        return True


@pytest.fixture
def server(store_url, tmp_path):
    env = {
        "TSDB_HEADER_TIMEOUT_S": str(TIMEOUT_S),
        "TSDB_BODY_TIMEOUT_S": str(TIMEOUT_S),
        "TSDB_MAX_CONNECTIONS": "400",
    }
    with ServerProcess(store_url, extra_env=env, log_dir=tmp_path) as proc:
        yield proc


def test_half_open_requests_are_closed_and_others_served(server):
    head = b"POST /v2/notify HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\n"
    body = head + f"Content-Length: {len(NOTIFICATION)}\r\n\r\n".encode() + NOTIFICATION[:20]
    sockets = [_connect(server.port, head if i % 2 else body) for i in range(HALF_OPEN)]
    try:
        opened = time.monotonic()
        with httpx.Client(base_url=server.url, timeout=5) as http:
            # Served while every half-open socket is still held.
            assert http.get("/health").status_code == 200
            r = http.post("/v2/notify", content=NOTIFICATION, headers={"Content-Type": "application/json"})
            assert r.status_code == 200, r.text
            assert time.monotonic() - opened < TIMEOUT_S, "the check above must run before the timeout"
            deadline = opened + TIMEOUT_S + 10
            still_open = [s for s in sockets if not _closed_by_peer(s, max(0.0, deadline - time.monotonic()))]
            assert not still_open, f"{len(still_open)} of {HALF_OPEN} half-open sockets were not closed"
            assert http.get("/health").status_code == 200
            assert http.get("/v2/entities/E/attrs/v").json()["values"] == [1]
    finally:
        for s in sockets:
            s.close()


def test_connections_past_the_cap_get_503(store_url, tmp_path):
    env = {"TSDB_MAX_CONNECTIONS": "20", "TSDB_HEADER_TIMEOUT_S": "30"}
    with ServerProcess(store_url, extra_env=env, log_dir=tmp_path) as server:
        idle = [_connect(server.port, b"") for _ in range(20)]
        try:
            time.sleep(0.3)
            extra = _connect(server.port, b"GET /health HTTP/1.1\r\nHost: x\r\n\r\n")
            answer = extra.recv(4096)
            extra.close()
            assert answer.startswith(b"HTTP/1.1 503"), answer
        finally:
            for s in idle:
                s.close()
        time.sleep(0.3)
        assert httpx.get(server.url + "/health", timeout=5).status_code == 200


def test_disconnect_mid_body_is_one_log_line(server):
    head = b"POST /v2/notify HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\nContent-Length: %d\r\n\r\n" % len(
        NOTIFICATION
    )
    sock = _connect(server.port, head + NOTIFICATION[: len(NOTIFICATION) // 2])
    time.sleep(0.2)
    sock.close()
    deadline = time.monotonic() + 10
    while "disconnected before sending the whole body" not in server.output() and time.monotonic() < deadline:
        time.sleep(0.05)
    output = server.output()
    lines = [line for line in output.splitlines() if "disconnected before sending the whole body" in line]
    assert len(lines) == 1, output
    assert "Traceback" not in output and "notification failed" not in output, output
    assert httpx.get(server.url + "/health", timeout=5).status_code == 200
