"""Issue 27, limits at the edges: every route limits its body while it
reads it (a real server answers 413 before an oversized body is sent
whole); a request head has a size limit (431, counted as it arrives); a
refused tenant header never becomes a metrics label; the rejected store
has a bound over all tenants, since refused tenant headers are whatever a
sender invents."""

from __future__ import annotations

import json
import select
import socket
import threading
import time

import httpx
import psutil
import pytest

from tests.support.server import ServerProcess

MIB = 1 << 20
BAD = b'{"not": "a notification"}'
LD_WRITE = {"id": "urn:ngsi-ld:V:1", "type": "V", "speed": {"type": "Property", "value": 1}}
# (method, path, headers, a body the route would accept, the limit's setting)
ROUTES = [
    ("POST", "/v2/op/query", {}, {"entities": [{"id": "x"}]}, "TSDB_MAX_REQUEST_BODY_BYTES"),
    ("POST", "/ngsi-ld/v1/temporal/entityOperations/query", {}, {"type": "Query"}, "TSDB_MAX_REQUEST_BODY_BYTES"),
    ("POST", "/ngsi-ld/v1/temporal/entities", {}, LD_WRITE, "TSDB_MAX_BODY_BYTES"),
    ("PUT", "/v2/notify/subscriptions/s1", {}, {"attrs": ["id", "a"]}, "TSDB_MAX_REQUEST_BODY_BYTES"),
    ("POST", "/grafana/simplejson/query", {}, {"targets": []}, "TSDB_MAX_REQUEST_BODY_BYTES"),
    ("POST", "/grafana/simplejson/search", {}, {"target": ""}, "TSDB_MAX_REQUEST_BODY_BYTES"),
]


def padded(doc: dict, size: int) -> bytes:
    """``doc`` as JSON, padded with spaces to ``size`` bytes."""
    raw = json.dumps(doc).encode()
    return raw + b" " * (size - len(raw))


@pytest.fixture
def limited(client_factory, tmp_path):
    """Small limits, so oversized bodies stay cheap to send."""
    with client_factory(
        str(tmp_path / "tsdb.duckdb"), max_request_body_bytes=64 * 1024, max_body_bytes=128 * 1024
    ) as client:
        yield client


@pytest.mark.parametrize(("method", "path", "headers", "doc", "setting"), ROUTES)
def test_every_route_limits_its_body(limited, method, path, headers, doc, setting):
    limit = 64 * 1024 if setting == "TSDB_MAX_REQUEST_BODY_BYTES" else 128 * 1024
    h = {"Content-Type": "application/json", **headers}
    ok = limited.request(method, path, content=padded(doc, limit), headers=h)
    assert ok.status_code != 413, ok.text
    for body in (padded(doc, limit + 1), iter([padded(doc, limit), b" "])):  # declared, then chunked
        refused = limited.request(method, path, content=body, headers=h)
        assert refused.status_code == 413, refused.text
        answer = refused.json()
        if path.startswith("/ngsi-ld/"):
            assert answer["type"].endswith("/InvalidRequest") and setting in answer["detail"]
        else:
            assert answer["error"] == "PayloadTooLarge" and setting in answer["description"]


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    path = tmp_path_factory.mktemp("limits") / "tsdb.duckdb"
    with ServerProcess(path, extra_env={"TSDB_MAX_HEADER_BYTES": str(64 * 1024)}) as running:
        yield running


def _raw(server, request: bytes, then=b"", chunks: int = 0, timeout: float = 10.0) -> bytes:
    """Send ``request``, then ``then`` up to ``chunks`` times (stopping when the
    server closes), and return what the server answered."""
    with socket.create_connection(("127.0.0.1", server.port), timeout=timeout) as s:
        s.sendall(request)
        try:
            for _ in range(chunks):
                s.sendall(then)
        except OSError:
            pass  # the server closed the connection: it has answered
        answer = b""
        try:
            while chunk := s.recv(65536):
                answer += chunk
                if b"\r\n\r\n" in answer and not then:
                    break
        except OSError:
            pass
        return answer


@pytest.mark.parametrize("path", ["/v2/op/query", "/grafana/simplejson/query", "/ngsi-ld/v1/temporal/entities"])
def test_an_oversized_chunked_body_is_refused_while_it_arrives(server, path):
    """No Content-Length: the server counts, answers 413 past the limit and
    stops reading; the client never gets to send its 64 MiB."""
    head = f"POST {path} HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\nTransfer-Encoding: chunked\r\n\r\n"
    chunk = b"%x\r\n%s\r\n" % (256 * 1024, b" " * 256 * 1024)
    with socket.create_connection(("127.0.0.1", server.port), timeout=10) as s:
        s.sendall(head.encode())
        sent, answer = 0, b""
        while sent < 64 * MIB and not answer:
            try:
                s.sendall(chunk)
            except OSError:
                break  # closed: it has answered
            sent += len(chunk)
            if select.select([s], [], [], 0)[0]:
                answer = s.recv(65536)
        answer = answer or s.recv(65536)
    assert answer.startswith(b"HTTP/1.1 413"), answer[:200]
    assert sent < 32 * MIB  # answered long before the body was complete


def test_request_heads_have_a_size_limit(server):
    big = b"GET /health HTTP/1.1\r\nHost: x\r\nX-Big: " + b"a" * (100 * 1024) + b"\r\n\r\n"
    assert _raw(server, big).startswith(b"HTTP/1.1 431")
    # a header that never ends: cut off after the limit, not buffered
    endless = _raw(server, b"GET /health HTTP/1.1\r\nHost: x\r\nX-Big: ", then=b"a" * 65536, chunks=300)
    assert endless.startswith(b"HTTP/1.1 431")
    # the limit is on the whole head: many small headers too
    many = b"GET /health HTTP/1.1\r\nHost: x\r\n" + b"".join(b"X-H%d: %s\r\n" % (i, b"v" * 100) for i in range(1000))
    assert _raw(server, many + b"\r\n").startswith(b"HTTP/1.1 431")
    normal = httpx.get(server.url + "/health", headers={"X-Fine": "a" * 30_000}, timeout=10)
    assert normal.status_code == 200


def test_parallel_huge_headers_cost_neither_memory_nor_time(server):
    process = psutil.Process(server.proc.pid)
    before = process.memory_info().rss

    def attack():
        _raw(server, b"GET /health HTTP/1.1\r\nHost: x\r\nX-Big: ", then=b"a" * MIB, chunks=40)

    threads = [threading.Thread(target=attack) for _ in range(6)]
    for thread in threads:
        thread.start()
    started = time.monotonic()
    assert httpx.get(server.url + "/health", timeout=10).status_code == 200
    assert time.monotonic() - started < 1.0
    for thread in threads:
        thread.join(60)
    assert process.memory_info().rss - before < 64 * MIB


def test_a_refused_tenant_header_is_never_a_metrics_label(client):
    tenant = "x" * 200_000
    refused = client.post(
        "/v2/notify", content=BAD, headers={"Content-Type": "application/json", "Fiware-Service": tenant}
    )
    assert refused.status_code == 400
    stored = client.post(
        "/v2/notify", content=BAD, headers={"Content-Type": "application/json", "Fiware-Service": "Good_One"}
    )
    assert stored.status_code == 400
    text = client.get("/metrics").text
    assert max(len(line) for line in text.splitlines()) < 1000
    assert 'tenant="invalid"' in text and 'tenant="good_one"' in text


def test_the_rejected_store_is_bounded_over_all_tenants(client_factory, store_url):
    settings = {"rejected_max_per_tenant": 1, "rejected_max_total": 5, "rejected_max_total_bytes": 64 * 1024}
    with client_factory(store_url, **settings) as client:
        for n in range(20):  # 20 tenants nobody has, each a refused header
            headers = {"Content-Type": "application/json", "Fiware-Service": f"bad-tenant-{n}!"}
            assert client.post("/v2/notify", content=BAD, headers=headers).status_code == 400
        kept = client.get("/v2/notify/rejected", params={"allTenants": "true"}).json()
        assert [row["tenant"] for row in kept] == [f"bad-tenant-{n}!" for n in range(19, 14, -1)]
        for n in range(3):  # bytes over all tenants: 40 KiB bodies, at most 64 KiB kept
            body = BAD + b" " * 40_000
            headers = {"Content-Type": "application/json", "Fiware-Service": f"big{n}"}
            assert client.post("/v2/notify", content=body, headers=headers).status_code == 400
        kept = client.get("/v2/notify/rejected", params={"allTenants": "true"}).json()
        assert [row["tenant"] for row in kept] == ["big2"]  # the newest is always kept
        metrics = client.get("/metrics").text
        assert 'tsdb_rejected_dropped_total{reason="count"}' in metrics
