"""``idPattern`` runs on RE2: a hostile pattern cannot freeze the process.

``^(.|.)*$!`` backtracks exponentially in Python's ``re`` (a 29-character
id took over 30 s, on the event loop, blocking ingest). With RE2 it answers
at once on every endpoint that takes a pattern, a concurrent ``/health`` and
notification are served meanwhile, and what RE2 cannot do (backreferences,
lookaround) is a 400 that names the syntax.
"""

from __future__ import annotations

import threading
import time

import httpx
import pytest

from tests.support.server import ServerProcess

HOSTILE = "^(.|.)*$!"
IDS = [f"urn:ngsi-ld:Room:{n:012d}" for n in range(40)]  # 29 characters each
assert len(IDS[0]) == 29


def _entity(eid: str, value: float) -> dict:
    return {
        "id": eid,
        "type": "Room",
        "temperature": {"type": "Number", "value": value},
        "TimeInstant": {"type": "DateTime", "value": "2024-05-01T10:00:00Z"},
    }


def _load(post) -> None:
    for i in range(0, len(IDS), 10):
        body = {"subscriptionId": "s", "data": [_entity(eid, n) for n, eid in enumerate(IDS[i : i + 10])]}
        r = post("/v2/notify", json=body, headers={"Content-Type": "application/json"})
        assert r.status_code == 200, r.text


def _requests(pattern: str) -> list[tuple[str, str, dict]]:
    """(method, path, kwargs) for every entry point that takes a pattern."""
    return [
        ("GET", "/v2/types/Room", {"params": {"idPattern": pattern}}),
        ("GET", "/v2/attrs", {"params": {"idPattern": pattern}}),
        ("GET", "/v2/entities", {"params": {"idPattern": pattern}}),
        ("POST", "/v2/op/query", {"json": {"entities": [{"idPattern": pattern}]}}),
        ("GET", "/grafana/infinity/series", {"params": {"attrs": "temperature", "idPattern": pattern}}),
        ("GET", "/grafana/infinity/entities", {"params": {"idPattern": pattern}}),
        (
            "POST",
            "/grafana/simplejson/query",
            {"json": {"targets": [{"target": "*/temperature", "payload": {"idPattern": pattern}}]}},
        ),
        (
            "POST",
            "/grafana/simplejson/query",
            {
                "json": {
                    "targets": [{"target": "*/temperature"}],
                    "adhocFilters": [{"key": "entity", "operator": "=~", "value": pattern}],
                }
            },
        ),
    ]


def test_hostile_pattern_answers_at_once_everywhere(client):
    _load(client.post)
    for method, path, kwargs in _requests(HOSTILE):
        start = time.monotonic()
        r = client.request(method, path, **kwargs)
        elapsed = time.monotonic() - start
        assert r.status_code == 200, (path, r.text)
        assert elapsed < 2.0, (path, elapsed)
        body = r.json()
        assert body == [] or all(not frame.get("datapoints") for frame in body), (path, body)


def test_patterns_still_match(client):
    _load(client.post)
    r = client.get("/v2/entities", params={"idPattern": r"Room:0{10}0[12]$"})
    assert sorted(e["id"] for e in r.json()) == [IDS[1], IDS[2]]
    r = client.post("/v2/op/query", json={"entities": [{"idPattern": "(?i)ROOM:0+3$"}]})
    assert [e["id"] for e in r.json()] == [IDS[3]]


@pytest.mark.parametrize("pattern", [r"(a)\1", "(?=Room)", "(?!x)", "(?<=a)b", "(?<!a)b"])
def test_unsupported_syntax_is_a_400_naming_re2(client, pattern):
    for method, path, kwargs in _requests(pattern):
        r = client.request(method, path, **kwargs)
        assert r.status_code == 400, (path, r.text)
        assert "RE2 syntax" in r.json()["description"], (path, r.json())


def test_hostile_pattern_does_not_block_other_clients(store_url, tmp_path):
    """A real server: while clients hammer it with the hostile pattern,
    /health and notifications keep answering promptly."""
    with ServerProcess(store_url, log_dir=tmp_path) as server, httpx.Client(base_url=server.url, timeout=10) as http:
        _load(http.post)
        stop = threading.Event()
        errors: list[str] = []

        def hammer() -> None:
            with httpx.Client(base_url=server.url, timeout=30) as own:
                while not stop.is_set():
                    r = own.get("/v2/types/Room", params={"idPattern": HOSTILE})
                    if r.status_code != 200:
                        errors.append(r.text)

        threads = [threading.Thread(target=hammer) for _ in range(2)]
        for t in threads:
            t.start()
        try:
            time.sleep(0.2)
            for n in range(5):
                start = time.monotonic()
                assert http.get("/health").status_code == 200
                r = http.post(
                    "/v2/notify",
                    json={"subscriptionId": "s", "data": [_entity(IDS[0], 100 + n)]},
                    headers={"Content-Type": "application/json"},
                )
                assert r.status_code == 200, r.text
                assert time.monotonic() - start < 2.0
        finally:
            stop.set()
            for t in threads:
                t.join()
        assert not errors
