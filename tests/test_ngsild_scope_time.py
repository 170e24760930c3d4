"""Scopes with time (ETSI GS CIM 009 V1.9.1 clauses 4.18, 4.19): an entity
created through the temporal API with a ``scope`` is accepted, and
``scopeQ`` over a window honours when each scope was valid: a scope
replaced mid-window bounds the instances each scope matches.

A scope written with instances holds from the earliest of them (the
observation it came with), until the next scope; an entity's first scope
also covers what was observed before it (a scope is given at creation).
"""

from __future__ import annotations

import pytest

from tests.ngsild_fixtures import ENTITIES, H, get, ids

V = "urn:ngsi-ld:Vehicle:s1"
W = "urn:ngsi-ld:Vehicle:s2"


def speed(minute: int, value: float) -> dict:
    return {"type": "Property", "value": value, "observedAt": f"2024-01-01T10:{minute:02d}:00Z"}


@pytest.fixture
def scoped(client):
    """V: /Madrid/Centro for minutes 0-4, then /Madrid/Norte from minute 5
    (an upsert with the new scope and the instances observed under it); W:
    /Company all along."""
    first = {"id": V, "type": "Vehicle", "scope": "/Madrid/Centro", "speed": [speed(m, m) for m in range(5)]}
    response = client.post(ENTITIES, json=first, headers=H)
    assert response.status_code == 201, response.text  # accepted with its scope (clause 4.18)
    later = {"id": V, "type": "Vehicle", "scope": "/Madrid/Norte", "speed": [speed(m, m) for m in range(5, 10)]}
    assert client.post(ENTITIES, json=later, headers=H).status_code == 204
    other = {"id": W, "type": "Vehicle", "scope": ["/Company", "/Madrid/Centro"], "speed": [speed(3, 30)]}
    assert client.post(ENTITIES, json=other, headers=H).status_code == 201
    return client


WINDOW = {"type": "Vehicle", "attrs": "speed", "timerel": "between", "timeAt": "2024-01-01T10:00:00Z",
          "endTimeAt": "2024-01-01T11:00:00Z"}  # fmt: skip


def speeds(response) -> dict[str, list]:
    return {e["id"]: [i["value"] for i in e.get("speed", [])] for e in response.json()}


def test_each_scope_matches_the_instances_of_its_time(scoped):
    """Clause 4.19 over a window: each scope selects the instances observed
    while it was the entity's scope."""
    assert speeds(get(scoped, {**WINDOW, "scopeQ": "/Madrid/Centro"})) == {V: [0, 1, 2, 3, 4], W: [30]}
    assert speeds(get(scoped, {**WINDOW, "scopeQ": "/Madrid/Norte"})) == {V: [5, 6, 7, 8, 9]}
    assert speeds(get(scoped, {**WINDOW, "scopeQ": "/Madrid/#"})) == {V: list(range(10)), W: [30]}
    assert speeds(get(scoped, {**WINDOW, "scopeQ": "/Company"})) == {W: [30]}


def test_a_window_inside_one_scope_sees_only_that_scope(scoped):
    early = {**WINDOW, "endTimeAt": "2024-01-01T10:04:00Z"}
    assert ids(get(scoped, {**early, "scopeQ": "/Madrid/Norte"})) == []
    late = {**WINDOW, "timeAt": "2024-01-01T10:06:00Z"}
    assert ids(get(scoped, {**late, "scopeQ": "/Madrid/Centro"})) == []
    assert speeds(get(scoped, {**late, "scopeQ": "/Madrid/Norte"})) == {V: [6, 7, 8, 9]}


def test_the_bounds_hold_for_every_representation_and_read(scoped):
    """The scope's span bounds lastN, the simplified form, the retrieve and
    aggregation alike."""
    centro = {**WINDOW, "scopeQ": "/Madrid/Centro"}
    assert speeds(get(scoped, {**centro, "lastN": "2"}))[V] == [3, 4]
    simple = get(scoped, {**centro, "format": "temporalValues", "id": V}).json()[0]
    assert [v for v, _ in simple["speed"]["values"]] == [0, 1, 2, 3, 4]
    one = get(scoped, path=f"{ENTITIES}/{V}", params={**centro, "type": None})
    assert [i["value"] for i in one.json()["speed"]] == [0, 1, 2, 3, 4]
    agg = get(scoped, {**centro, "id": V, "format": "aggregatedValues", "aggrMethods": "max,totalCount"}).json()[0]
    assert agg["speed"]["max"][0][0] == 4 and agg["speed"]["totalCount"][0][0] == 5


def test_as_of_an_instant_the_scope_then_decides(scoped):
    assert ids(get(scoped, {"type": "Vehicle", "scopeQ": "/Madrid/Centro", "asOf": "2024-01-01T10:03:30Z"})) == [V, W]
    assert ids(get(scoped, {"type": "Vehicle", "scopeQ": "/Madrid/Centro", "asOf": "2024-01-01T10:07:00Z"})) == [W]
