"""A client that sends half a body and disconnects, on any POST/PUT route
that reads a body, is one log line (a warning): no traceback, no 500
(the notify fast path has its own test in test_slow_clients). A real server
process: only uvicorn turns a closed socket into ``ClientDisconnect``."""

from __future__ import annotations

import socket
import time

import httpx
import pytest

from tests.support.server import ServerProcess

MARK = "disconnected before sending the whole body"

ROUTES = [
    ("POST", "/v2/op/query", "application/json", b'{"entities":[{"idPattern":".*"}],"attrs":["v"]}'),
    (
        "POST",
        "/grafana/simplejson/query",
        "application/json",
        b'{"targets":[{"target":"E/v"}],"range":{"from":"2024-01-01T00:00:00Z","to":"2024-01-02T00:00:00Z"}}',
    ),
    ("POST", "/grafana/simplejson/search", "application/json", b'{"target":"some search text"}'),
    ("PUT", "/v2/notify/subscriptions/s1", "application/json", b'{"attrs":["id","v"],"entityType":"T"}'),
    (
        "POST",
        "/ngsi-ld/v1/temporal/entities",
        "application/json",
        b'{"id":"urn:ngsi-ld:T:1","type":"T","v":[{"type":"Property","value":1}]}',
    ),
]


@pytest.fixture
def server(store_url, tmp_path):
    with ServerProcess(store_url, log_dir=tmp_path) as proc:
        yield proc


def _half_body_then_close(port: int, method: str, path: str, media_type: str, body: bytes) -> None:
    head = (
        f"{method} {path} HTTP/1.1\r\nHost: x\r\nContent-Type: {media_type}\r\nContent-Length: {len(body)}\r\n\r\n"
    ).encode()
    with socket.create_connection(("127.0.0.1", port), timeout=5) as sock:
        sock.sendall(head + body[: len(body) // 2])
        time.sleep(0.2)


def _lines_about(server: ServerProcess, before: int, timeout: float = 10) -> list[str]:
    deadline = time.monotonic() + timeout
    while True:
        lines = [line for line in server.output().splitlines()[before:] if MARK in line]
        if lines or time.monotonic() > deadline:
            return lines
        time.sleep(0.05)


def test_disconnect_mid_body_is_one_log_line(server):
    """One server per backend, every body-reading route in turn."""
    for method, path, media_type, body in ROUTES:
        before = len(server.output().splitlines())
        _half_body_then_close(server.port, method, path, media_type, body)
        lines = _lines_about(server, before)
        time.sleep(0.2)  # anything logged after the line would show up now
        output = "\n".join(server.output().splitlines()[before:])
        assert len(lines) == 1, f"{method} {path}:\n{output}"
        assert f"{method} {path}" in lines[0], lines[0]
        assert "Traceback" not in output and "InternalError" not in output and " 500" not in output, output
    assert httpx.get(server.url + "/health", timeout=5).status_code == 200
    # The request metric records each disconnect as a 400, never a 500.
    text = httpx.get(server.url + "/metrics", timeout=5).text
    errors = [
        line
        for line in text.splitlines()
        if line.startswith("tsdb_http_request_duration_seconds_count") and 'status="500"' in line
    ]
    assert not errors, errors
