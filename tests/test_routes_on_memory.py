"""The faces on the in-memory store (``http.memory.MemoryStore``): a route
test needs no database when what it tests is the route (parameters, shapes,
error answers, which write it asks for). Each face answers here as it does
on the backends (``test_memory_querier.py`` holds the querier to them).
"""

from __future__ import annotations

from datetime import UTC, datetime, timedelta

import pytest
from fastapi.testclient import TestClient

from tsdb_service.app import create_app
from tsdb_service.core.config import Settings
from tsdb_service.core.query import SeriesRef
from tsdb_service.http.memory import MemoryStore
from tsdb_service.read.memory import MemoryQuerier, sample
from tsdb_service.write.ops import DeleteSamples

T0 = datetime(2024, 5, 1, 10, 0, tzinfo=UTC)
SPEED, MODE, WHERE = (
    SeriesRef(1, "/", "Robot:1", "Robot", "speed"),
    SeriesRef(2, "/", "Robot:1", "Robot", "mode"),
    SeriesRef(3, "/", "Robot:1", "Robot", "location"),
)


@pytest.fixture
def store() -> MemoryStore:
    querier = MemoryQuerier([("acme", SPEED), ("acme", MODE), ("acme", WHERE)])
    rows = []
    for i in range(6):
        t = T0 + timedelta(minutes=i)
        rows += [
            sample(i + 1, 1, t, float(i), atype="Number"),
            sample(i + 1, 2, t, ["idle", "mowing"][i % 2], atype="Text"),
            sample(i + 1, 3, t, None, atype="geo:json", geo={"type": "Point", "coordinates": [0.1 * i, 1.0]}),
        ]
    querier.add_samples(rows)
    return MemoryStore(querier)


@pytest.fixture
def client(store, tmp_path) -> TestClient:
    with TestClient(create_app(Settings(db=str(tmp_path / "unused.duckdb")), store=store)) as c:
        yield c


ACME = {"Fiware-Service": "acme"}


def test_quantumleap_history_with_last_n(client):
    answer = client.get("/v2/entities/Robot:1/attrs/speed", params={"lastN": 2}, headers=ACME)
    assert answer.status_code == 200, answer.text
    assert answer.json() == {
        "id": "Robot:1",
        "type": "Robot",
        "attrName": "speed",
        "index": ["2024-05-01T10:04:00.000+00:00", "2024-05-01T10:05:00.000+00:00"],
        "values": [4.0, 5.0],
    }


def test_quantumleap_aggregation(client):
    answer = client.get("/v2/entities/Robot:1/attrs/speed", params={"aggrMethod": "sum"}, headers=ACME)
    assert answer.json()["values"] == [15.0]


def test_quantumleap_geo_query(client):
    near = {"georel": "near;maxDistance:20000", "geometry": "point", "coords": "1.0,0.0"}
    answer = client.get("/v2/entities/Robot:1/attrs/mode", params=near, headers=ACME)
    assert answer.status_code == 200, answer.text
    assert answer.json()["values"][0] == "idle"


def test_error_shapes_are_the_routes(client):
    answer = client.get("/v2/entities/Robot:1", params={"lastN": "x"}, headers=ACME)
    assert answer.status_code == 400 and set(answer.json()) == {"error", "description"}
    problem = client.get("/ngsi-ld/v1/temporal/entities", params={"type": "Robot", "timerel": "sometime"})
    assert problem.status_code == 400 and {"type", "title"} <= set(problem.json())


def test_a_delete_asks_for_the_right_write(client, store):
    answer = client.delete("/v2/entities/Robot:1", headers=ACME)
    assert answer.status_code == 204, answer.text
    assert store.written == [DeleteSamples((1, 2, 3), None, None)]


def test_grafana_rows(client):
    answer = client.get("/grafana/infinity/latest", params={"type": "Robot", "attrs": "speed,mode"}, headers=ACME)
    assert answer.status_code == 200, answer.text
    [row] = answer.json()
    assert (row["speed"], row["mode"]) == (5.0, "mowing")


def test_ngsild_temporal_retrieve(client):
    answer = client.get(
        "/ngsi-ld/v1/temporal/entities/Robot:1",
        params={"attrs": "speed", "lastN": 1},
        headers={"NGSILD-Tenant": "acme"},
    )
    assert answer.status_code == 200, answer.text
    assert [i["value"] for i in answer.json()["speed"]] == [5.0]
