"""No database call on the event loop: every route reads through ``Store.read``.

The app runs on the real backend. Its database entry points (DuckDB's
per-thread cursor, PostgreSQL's connection pool) are wrapped with a check
that notes every call and whether it came from a thread running an event
loop; every route family that reads is then hit, and no call may have come
from the loop. The wrapper only observes: the calls go to the database.
"""

from __future__ import annotations

import asyncio
import functools
import threading
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field

import pytest

from tsdb_service.parse import ValuesLayout
from tsdb_service.read.off_loop import MEMORY_ONLY, NeedsDatabase
from tsdb_service.write.ops import PutLayout

T0 = "2024-05-01T10:00:00.000Z"
T1 = "2024-05-01T10:05:00.000Z"
V2 = {"Content-Type": "application/json", "Fiware-Service": "offloop"}
LD = {"Content-Type": "application/json", "NGSILD-Tenant": "offloop"}
ROBOT = "urn:ngsi-ld:Robot:r1"


@dataclass
class DatabaseCalls:
    """Database entry-point calls seen, and the routes that made one on the loop."""

    total: int = 0
    on_loop: list[str] = field(default_factory=list)
    lock: threading.Lock = field(default_factory=threading.Lock)

    def wrap(self, enter: Callable) -> Callable:
        @functools.wraps(enter)
        def checked(*args, **kwargs):
            try:
                asyncio.get_running_loop()
                loop_thread = True
            except RuntimeError:
                loop_thread = False
            with self.lock:
                self.total += 1
                if loop_thread:
                    self.on_loop.append(threading.current_thread().name)
            return enter(*args, **kwargs)

        return checked


def watch(store) -> DatabaseCalls:
    """Wrap the store's database entry points (what every read goes through)."""
    calls = DatabaseCalls()
    if store.backend == "duckdb":
        store.cursor = calls.wrap(store.cursor)
    else:
        store.pool.connection = calls.wrap(store.pool.connection)
    return calls


def v2(eid: str, at: str, temperature: float, lon: float) -> dict:
    return {
        "subscriptionId": "off-loop",
        "data": [
            {
                "id": eid,
                "type": "Room",
                "TimeInstant": {"type": "DateTime", "value": at},
                "temperature": {"type": "Number", "value": temperature},
                "open": {"type": "Boolean", "value": temperature > 21},
                "location": {"type": "geo:json", "value": {"type": "Point", "coordinates": [lon, 40.0]}},
            }
        ],
    }


@pytest.fixture
def watched(client, notify) -> Iterator[tuple[object, DatabaseCalls]]:
    for i, (eid, lon) in enumerate((("room1", -3.70), ("room2", -3.60))):
        notify(client, v2(eid, T0, 20.0 + i, lon), V2)
        notify(client, v2(eid, T1, 22.0 + i, lon), V2)
    created = client.post(
        "/ngsi-ld/v1/temporal/entities",
        json={"id": ROBOT, "type": "Robot", "speed": [{"type": "Property", "value": 1.5, "observedAt": T0}]},
        headers=LD,
    )
    assert created.status_code == 201, created.text
    bad = client.post("/v2/notify", content=b"{not json", headers=V2)
    assert bad.status_code == 400
    calls = watch(client.app.state.store)
    yield client, calls
    assert calls.on_loop == [], f"database calls on the event loop: {calls.on_loop}"


GETS = [
    "/v2/entities",
    "/v2/entities/room1",
    "/v2/entities/room1/attrs/temperature?lastN=1",
    "/v2/entities/room1/attrs/temperature/value?aggrMethod=avg",
    "/v2/types/Room?attrs=temperature",
    "/v2/types/Room/attrs/temperature/value",
    "/v2/attrs?attrs=temperature",
    "/v2/attrs/temperature/value",
    "/v2/entities?georel=near;maxDistance:20000&geometry=point&coords=40.0,-3.7",
    "/v2/types/Room?georel=coveredBy&geometry=box&coords=39.9,-3.8;40.1,-3.65",
    "/grafana/infinity/series?type=Room&attrs=temperature",
    "/grafana/infinity/latest?type=Room&attrs=temperature",
    "/grafana/infinity/states?type=Room&attrs=open",
    "/grafana/infinity/events?type=Room&attrs=open",
    "/grafana/infinity/positions?type=Room&attrs=temperature",
    "/grafana/infinity/aggregate?type=Room&attrs=temperature",
    "/grafana/infinity/entities?type=Room",
    "/ui/tenants",
    "/ngsi-ld/v1/temporal/entities?type=Robot",
    f"/ngsi-ld/v1/temporal/entities/{ROBOT}",
    "/v2/export?type=Room",
    "/v2/export?type=Room&format=parquet",
    "/health",
    "/metrics",
    "/v2/notify/rejected",
    "/v2/notify/subscriptions",
]


@pytest.mark.parametrize("path", GETS)
def test_get_routes_read_off_the_loop(watched, path):
    client, calls = watched
    headers = LD if path.startswith("/ngsi-ld/") else V2
    response = client.get(path, headers=headers)
    assert response.status_code == 200, response.text
    assert response.content
    assert calls.on_loop == []


def test_the_check_sees_database_reads(watched):
    client, calls = watched
    assert client.get("/v2/notify/rejected", headers=V2).status_code == 200
    assert calls.total > 0


SIMPLEJSON = [
    ("/grafana/simplejson/search", {"target": ""}),
    ("/grafana/simplejson/variable", {"payload": {"target": "entities"}}),
    ("/grafana/simplejson/metrics", {}),
    ("/grafana/simplejson/metric-payload-options", {"metric": "room1/temperature", "payload": "path", "name": "path"}),
    ("/grafana/simplejson/tag-values", {"key": "entity"}),
    (
        "/grafana/simplejson/query",
        {"range": {"from": T0, "to": T1}, "targets": [{"target": "room1/temperature", "refId": "A"}]},
    ),
    (
        "/grafana/simplejson/annotations",
        {"range": {"from": T0, "to": T1}, "annotation": {"query": "room1/open=true"}},
    ),
    ("/v2/op/query", {"entities": [{"idPattern": "room.*"}], "attrs": ["temperature"]}),
    ("/ngsi-ld/v1/temporal/entityOperations/query", {"type": "Query", "entities": [{"type": "Robot"}]}),
]


@pytest.mark.parametrize(("path", "body"), SIMPLEJSON, ids=[p for p, _ in SIMPLEJSON])
def test_post_reads_off_the_loop(watched, path, body):
    client, calls = watched
    headers = LD if path.startswith("/ngsi-ld/") else V2
    response = client.post(path, json=body, headers=headers)
    assert response.status_code == 200, response.text
    assert calls.total > 0


def test_writes_that_read_first_do_so_off_the_loop(watched):
    """Deletes look up their target series, NGSI-LD writes the entity's."""
    client, calls = watched
    more = {"speed": [{"type": "Property", "value": 2.5, "observedAt": T1}]}
    assert client.post(f"/ngsi-ld/v1/temporal/entities/{ROBOT}/attrs", json=more, headers=LD).status_code == 204
    assert client.delete("/v2/entities/room2", headers=V2).status_code == 204
    assert client.delete("/v2/types/Room", headers=V2).status_code == 204
    assert client.delete(f"/ngsi-ld/v1/temporal/entities/{ROBOT}", headers=LD).status_code == 204
    assert calls.total > 0


def test_lastN_from_memory_makes_no_database_call(watched, backend):
    """The memory-first half of the rule: a warm tail (DuckDB's) answers on the loop."""
    if backend != "duckdb":
        pytest.skip("in-memory tails are DuckDB's")
    client, calls = watched
    path = "/v2/entities/room1/attrs/temperature?lastN=1"
    assert client.get(path, headers=V2).status_code == 200  # warms the tail
    before = calls.total
    response = client.get(path, headers=V2)
    assert response.status_code == 200
    assert response.json()["values"] == [22.0]
    assert calls.total == before


# --- 'values' layouts on PostgreSQL: another replica's registration --------------------


def _values_notification(client, subscription: str, row: list) -> object:
    body = {"subscriptionId": subscription, "data": [row]}
    return client.post("/v2/notify", json=body, headers={**V2, "Ngsiv2-AttrsFormat": "values"})


@pytest.fixture
def replicas(backend, store_url, client_factory):
    """An app and a second store on the same PostgreSQL database (a replica)."""
    if backend != "postgresql":
        pytest.skip("several processes share one database only on PostgreSQL")
    from tsdb_service.storage.postgres.store import PostgresStore

    with client_factory(store_url) as client:
        other = PostgresStore(store_url, pool_size=1, writer_threads=1)
        try:
            yield client, other
        finally:
            other.close()


def test_layout_of_another_replica_is_read_off_the_loop(replicas):
    client, other = replicas
    other.write_sync([PutLayout("offloop", "sub-b", ValuesLayout(("id", "type", "temperature"), None, None))])
    calls = watch(client.app.state.store)
    response = _values_notification(client, "sub-b", ["room9", "Room", 19.5])
    assert response.status_code == 200, response.text
    assert calls.total > 0 and calls.on_loop == []
    got = client.get("/v2/entities/room9/attrs/temperature/value", headers=V2)
    assert got.json()["values"] == [19.5]


def test_layout_miss_on_the_loop_raises_before_any_query(replicas):
    client, _ = replicas
    store = client.app.state.store
    calls = watch(store)
    token = MEMORY_ONLY.set(True)
    try:
        with pytest.raises(NeedsDatabase):
            store.values_layout("offloop", "never-registered")
    finally:
        MEMORY_ONLY.reset(token)
    assert calls.total == 0
    assert store.values_layout("offloop", "never-registered") is None  # off the loop: it looked
    assert calls.total == 1


def test_layout_registered_again_elsewhere_is_picked_up(replicas, monkeypatch):
    """A known layout is read again once older than ``LAYOUTS_MAX_AGE``, so
    a replica's new attribute list replaces the one this process holds."""
    from tsdb_service.storage.postgres import store as pg_store

    client, other = replicas
    put = client.put("/v2/notify/subscriptions/sub-c", json={"attrs": ["id", "type", "temperature"]}, headers=V2)
    assert put.status_code == 200
    assert _values_notification(client, "sub-c", ["room7", "Room", 18.0]).status_code == 200
    other.write_sync([PutLayout("offloop", "sub-c", ValuesLayout(("type", "id", "humidity"), None, None))])
    monkeypatch.setattr(pg_store, "LAYOUTS_MAX_AGE", 0.0)
    calls = watch(client.app.state.store)
    assert _values_notification(client, "sub-c", ["Room", "room7", 55.0]).status_code == 200
    assert calls.on_loop == []
    got = client.get("/v2/entities/room7/attrs/humidity/value", headers=V2)
    assert got.json()["values"] == [55.0]
