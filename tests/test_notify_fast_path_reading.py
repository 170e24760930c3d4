"""The notify fast path reads a request as the framework's routes do (a
real server process: only uvicorn splits a body into several ASGI messages).

It reads the raw ASGI scope and ``receive`` itself, without Starlette's
``Request``: a body that arrives in pieces or chunked is the same body, a
header sent twice is seen twice (two different tenants are refused and kept,
as on every route), and a chunked body over the limit is refused and kept
with its first bytes and its size.
"""

from __future__ import annotations

import socket
import time

import httpx
import orjson
import pytest

from tests.support.server import ServerProcess

LIMIT = 4096


def _entity(value: float) -> dict:
    return {"id": "Tank:1", "type": "Tank", "level": {"type": "Number", "value": value, "metadata": {}}}


def _body(value: float, padding: int = 0) -> bytes:
    return orjson.dumps({"subscriptionId": "s" * max(padding, 1), "data": [_entity(value)]})


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    path = tmp_path_factory.mktemp("fastpath")
    with ServerProcess(path / "tsdb.duckdb", extra_env={"TSDB_MAX_BODY_BYTES": str(LIMIT)}, log_dir=path) as proc:
        yield proc


def _exchange(port: int, head: str, pieces: list[bytes]) -> bytes:
    """Send ``head`` then each piece apart (their own TCP segments), read the answer."""
    with socket.create_connection(("127.0.0.1", port), timeout=10) as sock:
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        sock.sendall(head.encode())
        for piece in pieces:
            time.sleep(0.02)
            sock.sendall(piece)
        answer = b""
        while b"\r\n\r\n" not in answer or len(answer) < _answer_length(answer):
            data = sock.recv(65536)
            if not data:
                break
            answer += data
    return answer


def _answer_length(answer: bytes) -> int:
    head, _, _ = answer.partition(b"\r\n\r\n")
    for line in head.split(b"\r\n")[1:]:
        name, _, value = line.partition(b":")
        if name.strip().lower() == b"content-length":
            return len(head) + 4 + int(value)
    return len(answer)


def _levels(server: ServerProcess, tenant: str) -> list[float]:
    answer = httpx.get(
        server.url + "/v2/entities/Tank:1/attrs/level", headers={"Fiware-Service": tenant}, params={"type": "Tank"}
    )
    return answer.json()["values"] if answer.status_code == 200 else []


def test_a_body_in_pieces_is_the_whole_body(server):
    body = _body(1.5)
    head = (
        "POST /v2/notify HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\nFiware-Service: pieces\r\n"
        f"Content-Length: {len(body)}\r\n\r\n"
    )
    answer = _exchange(server.port, head, [body[:10], body[10:40], body[40:]])
    assert answer.startswith(b"HTTP/1.1 200"), answer
    assert answer.endswith(b'"Notification successfully processed"')
    assert _levels(server, "pieces") == [1.5]


def test_a_chunked_body_is_the_whole_body(server):
    body = _body(2.5)
    head = (
        "POST /v2/notify HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\nFiware-Service: chunked\r\n"
        "Transfer-Encoding: chunked\r\n\r\n"
    )
    pieces = [b"%x\r\n%s\r\n" % (len(part), part) for part in (body[:25], body[25:])] + [b"0\r\n\r\n"]
    answer = _exchange(server.port, head, pieces)
    assert answer.startswith(b"HTTP/1.1 200"), answer
    assert _levels(server, "chunked") == [2.5]


def test_a_header_sent_twice_is_read_twice(server):
    body = _body(3.5)
    twice = "Fiware-Service: alpha\r\nFiware-Service: beta\r\n"
    head = (
        f"POST /v2/notify HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\n{twice}"
        f"Content-Length: {len(body)}\r\n\r\n"
    )
    answer = _exchange(server.port, head, [body])
    assert answer.startswith(b"HTTP/1.1 400"), answer
    assert b"conflicting tenant selectors" in answer
    kept = httpx.get(server.url + "/v2/notify/rejected", params={"allTenants": "true"}).json()
    assert any(row["tenant"] == "alpha,beta" for row in kept)

    same = "Fiware-Service: gamma\r\nFiware-Service: gamma\r\n"
    answer = _exchange(server.port, head.replace(twice, same), [body])
    assert answer.startswith(b"HTTP/1.1 200"), answer
    assert _levels(server, "gamma") == [3.5]


def test_a_chunked_body_over_the_limit_is_kept_with_its_size(server):
    body = _body(4.5, padding=2 * LIMIT)
    head = (
        "POST /v2/notify HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\nFiware-Service: big\r\n"
        "Transfer-Encoding: chunked\r\n\r\n"
    )
    parts = [body[i : i + 1000] for i in range(0, len(body), 1000)]
    answer = _exchange(server.port, head, [b"%x\r\n%s\r\n" % (len(p), p) for p in parts] + [b"0\r\n\r\n"])
    assert answer.startswith(b"HTTP/1.1 413"), answer
    assert f"notification of {len(body)} bytes exceeds the {LIMIT}-byte limit".encode() in answer
    kept = httpx.get(server.url + "/v2/notify/rejected", headers={"Fiware-Service": "big"}).json()
    assert [row["bodySize"] for row in kept] == [len(body)]
