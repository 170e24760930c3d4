"""Issue 27: no pattern a client sends runs outside RE2. NGSI-LD ``q``'s
``~=`` used Python's backtracking ``re``: a stored ``"a" * 30 + "!"`` and
``^(a+)+$`` took minutes and held the GIL, stalling every request. On both
backends, with the value really stored."""

from __future__ import annotations

import time

import pytest

from tests.ngsild_fixtures import ENTITIES, H, error_type, ld_notify
from tsdb_service.faces.ngsild import qlang

EVIL = "a" * 30 + "!"


@pytest.fixture
def noted(client):
    ld_notify(
        client,
        [
            {
                "id": "urn:ngsi-ld:Note:1",
                "type": "Note",
                "note": {"type": "Property", "value": EVIL, "observedAt": "2024-05-01T10:00:00Z"},
            }
        ],
    )
    return client


@pytest.mark.parametrize("op", ["~=", "!~="])
def test_catastrophic_patterns_take_linear_time(noted, op):
    started = time.monotonic()
    got = noted.get(ENTITIES, params={"type": "Note", "q": f'note{op}"^(a+)+$"'}, headers=H)
    assert got.status_code == 200, got.text
    assert time.monotonic() - started < 2.0
    assert [e["id"] for e in got.json()] == ([] if op == "~=" else ["urn:ngsi-ld:Note:1"])


def test_patterns_still_match(noted):
    got = noted.get(ENTITIES, params={"type": "Note", "q": 'note~="^a{30}!$"'}, headers=H)
    assert [e["id"] for e in got.json()] == ["urn:ngsi-ld:Note:1"]


@pytest.mark.parametrize("pattern", [r"(a)\1", "(?=a)a", "[", "x" * 600])
def test_patterns_re2_cannot_run_are_400(noted, pattern):
    got = noted.get(ENTITIES, params={"type": "Note", "q": f'note~="{pattern}"'}, headers=H)
    assert got.status_code == 400 and error_type(got) == "BadRequestData", got.text


def test_the_q_parser_compiles_with_re2():
    term = qlang.parse('a~="^(a+)+$"')
    assert type(term.value).__module__ == "re2"
