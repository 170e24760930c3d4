"""Service paths in queries: anchored, case-sensitive, hierarchical, unions."""

from __future__ import annotations

import pytest

from tsdb_service.core.errors import BadRequest
from tsdb_service.core.query import Scope
from tsdb_service.parse.request_context import service_paths


@pytest.mark.parametrize(
    ("header", "expected"),
    [
        (None, ("/",)),
        ("", ("/",)),
        ("/", ("/",)),
        ("/#", ("/",)),
        ("/a", ("/a",)),
        ("/a/", ("/a",)),
        ("/a/#", ("/a",)),
        ("/a, /b/c", ("/a", "/b/c")),
        ("/a,/a", ("/a",)),
        ("/a, /", ("/",)),
    ],
)
def test_header_parsing(header, expected):
    assert service_paths(header) == expected


@pytest.mark.parametrize("header", ["a", "/a//b", "/a,b", "/a b", "/a/#/c", ",".join(["/x"] * 51)])
def test_bad_headers(header):
    with pytest.raises(BadRequest):
        service_paths(header)


@pytest.mark.parametrize(
    ("query", "stored", "match"),
    [
        (("/",), "/", True),
        (("/",), "/anything/deep", True),
        (("/a",), "/a", True),
        (("/a",), "/a/b/c", True),
        (("/a",), "/ab", False),
        (("/a",), "/A", False),
        (("/a",), "/", False),
        (("/a/b",), "/a", False),
        (("/a", "/c"), "/c/d", True),
        (("/a.b",), "/aXb", False),  # no regex anywhere
    ],
)
def test_matching(query, stored, match):
    assert Scope("t", query).matches(stored) is match


def _note(eid: str) -> dict:
    return {
        "data": [
            {
                "id": eid,
                "type": "T",
                "TimeInstant": {"type": "DateTime", "value": "2024-01-01T00:00:00Z"},
                "v": {"type": "Number", "value": 1},
            }
        ]
    }


def test_over_http(client, notify):
    for eid, path in [("root", "/"), ("a", "/a"), ("ab", "/ab"), ("A", "/A"), ("ab2", "/a/b")]:
        notify(client, _note(eid), {"Fiware-ServicePath": path})

    def ids(header):
        r = client.get("/v2/types/T/attrs/v", headers={"Fiware-ServicePath": header} if header else {})
        assert r.status_code == 200, r.text
        return sorted(e["id"] for e in r.json()["entities"]) if r.json() else []

    assert ids(None) == ["A", "a", "ab", "ab2", "root"]
    assert ids("/a") == ["a", "ab2"]
    assert ids("/a/#") == ["a", "ab2"]
    assert ids("/A") == ["A"]
    assert ids("/a/b") == ["ab2"]
    assert ids("/ab,/A") == ["A", "ab"]
    assert ids("/nothing") == []
