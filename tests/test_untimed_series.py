"""Instances without observedAt stay in observedAt windows (read by their
row time) however they arrive. PostgreSQL lists the series that hold such
instances (``untimed_series``, migration 0009) and scans the row time only
for those, so every write path must list a series before its first such
instance is visible: a new series, a known one whose earlier instances all
had observedAt (the writer's autocommit path), and another replica's
write. On both backends (DuckDB reads every instance's row time anyway)."""

from __future__ import annotations

from datetime import UTC, datetime

import pytest

from tests.ngsild_fixtures import TENANT, get, ld_notify
from tsdb_service.core.config import Settings
from tsdb_service.core.model import AttrSample, EntitySample, Kind
from tsdb_service.core.query import EntityFilter, InstanceWindow, Scope
from tsdb_service.read.requests import SeriesSelect
from tsdb_service.storage import open_store
from tsdb_service.write.ops import AppendSamples

ROBOT = "urn:ngsi-ld:Robot:r1"
WINDOW = {"timerel": "after", "timeAt": "2024-01-01T00:00:00Z", "attrs": "speed"}


def speed(value: int, observed_at: str | None = None) -> dict:
    member = {"type": "Property", "value": value}
    if observed_at is not None:
        member["observedAt"] = observed_at
    return {"id": ROBOT, "type": "Robot", "speed": member}


def speeds(client) -> list:
    body = get(client, WINDOW, path=f"/ngsi-ld/v1/temporal/entities/{ROBOT}").json()
    found = body.get("speed", [])
    return sorted(i["value"] for i in (found if isinstance(found, list) else [found]))


def listed(store) -> set[int] | None:
    """The listed series on PostgreSQL (None on DuckDB, which keeps no list)."""
    if store.backend != "postgresql":
        return None
    with store.connection() as conn:
        return {row[0] for row in conn.execute("SELECT sid FROM untimed_series").fetchall()}


def speed_sid(store) -> int:
    [ref] = store.querier().series(SeriesSelect(Scope(TENANT), EntityFilter(ids=(ROBOT,)), ["speed"]))
    return ref.sid


def test_a_known_series_gets_an_instance_without_observed_at(client):
    store = client.app.state.store
    ld_notify(client, [speed(1, "2024-01-01T10:00:00Z")])
    assert listed(store) in (None, set())  # every instance so far has observedAt
    ld_notify(client, [speed(2)])  # a known series, no observedAt: the autocommit path on PostgreSQL
    assert listed(store) in (None, {speed_sid(store)})
    assert speeds(client) == [1, 2]


def test_a_new_series_without_observed_at(client):
    store = client.app.state.store
    ld_notify(client, [speed(3)])
    assert listed(store) in (None, {speed_sid(store)})
    if store.backend == "postgresql":  # remembered: the next instances send no listing
        assert store.memory.untimed._known == {speed_sid(store)}
    ld_notify(client, [speed(4, "2024-01-01T10:00:00Z")])
    assert speeds(client) == [3, 4]


def test_the_reader_scans_the_row_time_only_for_listed_series(client, monkeypatch):
    store = client.app.state.store
    if store.backend == "postgresql":
        from tsdb_service.storage.postgres import querier

        monkeypatch.setattr(querier, "UNTIMED_LOOKUP_FROM", 1)  # asked for one series too
    ld_notify(client, [speed(5, "2024-01-01T10:00:00Z")])
    q = store.querier()
    window = InstanceWindow("observedAt", datetime(2024, 1, 1, tzinfo=UTC), None)
    sid = speed_sid(store)
    if store.backend == "postgresql":
        assert q._untimed([sid], window) == []
        assert q._untimed([sid], InstanceWindow()) is None  # no window: nothing to test
    ld_notify(client, [speed(6)])
    if store.backend == "postgresql":
        assert q._untimed([sid], window) is None  # all listed: the plain test
    assert speeds(client) == [5, 6]


def test_another_replica_writes_an_instance_without_observed_at(client, store_url, monkeypatch):
    """A second store on the same database (another replica) lists what it
    writes; this one reads the list at each request, not from memory."""
    store = client.app.state.store
    if store.backend == "postgresql":
        from tsdb_service.storage.postgres import querier

        monkeypatch.setattr(querier, "UNTIMED_LOOKUP_FROM", 1)
    ld_notify(client, [speed(7, "2024-01-01T10:00:00Z")])
    assert speeds(client) == [7]
    if store.backend != "postgresql":
        pytest.skip("a DuckDB file has one writer process")
    other = open_store(Settings(db=store_url))
    try:
        attr = AttrSample("speed", "Property", Kind.INTEGER, num=8.0)
        moment = datetime(2024, 1, 1, 11, tzinfo=UTC)
        other.write_sync([AppendSamples([EntitySample(TENANT, "/", ROBOT, "Robot", moment, [attr])])])
    finally:
        other.close()
    assert speeds(client) == [7, 8]
