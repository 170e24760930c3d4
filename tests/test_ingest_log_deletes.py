"""A delete survives every restart and crash (DuckDB, through real server
processes): history removed by ``DELETE`` of an entity or a type, an
NGSI-LD instance deleted or replaced, or samples retention deleted, never
come back when the ingest log is replayed; and the samples acknowledged
after a delete are all there, once.

The log keeps a segment until a later one exists, so the records of the
samples just deleted are still in it at every stop and kill below: the
replay must know they were applied (the database holds the applied log
position) rather than guess it from the largest row id left.
"""

from __future__ import annotations

import time

import httpx

from tests.support.server import ServerProcess

TENANT = "deletes"
HEADERS = {"Fiware-Service": TENANT, "Fiware-ServicePath": "/"}
LD = "/ngsi-ld/v1/temporal/entities"
LD_HEADERS = {"NGSILD-Tenant": TENANT}


def notify(client: httpx.Client, entity_id: str, entity_type: str, value: int) -> None:
    entity = {
        "id": entity_id,
        "type": entity_type,
        "level": {"type": "Number", "value": value + 0.25},
        "TimeInstant": {"type": "DateTime", "value": f"2024-05-01T10:{value // 60:02d}:{value % 60:02d}Z"},
    }
    body = {"subscriptionId": "5f00000000000000000de1e7", "data": [entity]}
    answer = client.post("/v2/notify", json=body, headers=HEADERS)
    assert answer.status_code == 200, answer.text


def levels(client: httpx.Client, entity_id: str) -> list[float]:
    """The stored levels of ``entity_id``, oldest first ([] when it has none)."""
    answer = client.get(f"/v2/entities/{entity_id}/attrs/level", params={"limit": 1000}, headers=HEADERS)
    if answer.status_code == 404:
        return []
    assert answer.status_code == 200, answer.text
    body = answer.json()
    if body == []:  # the series is known, its samples are all gone
        return []
    return body["values"]


def delete(client: httpx.Client, path: str) -> None:
    answer = client.delete(path, headers=HEADERS)
    assert answer.status_code == 204, answer.text


def expected(values: range) -> list[float]:
    return [v + 0.25 for v in values]


def test_a_deleted_entity_and_type_stay_deleted_after_a_clean_restart(tmp_path):
    db = tmp_path / "clean.duckdb"
    with ServerProcess(db) as server, httpx.Client(base_url=server.url, timeout=30) as client:
        for v in range(10):
            notify(client, "Tank:1", "Tank", v)
            notify(client, "Tank:2", "Tank", v)
            notify(client, "Pump:1", "Pump", v)
        delete(client, "/v2/entities/Tank:1")
        delete(client, "/v2/types/Pump")
        assert levels(client, "Tank:1") == [] and levels(client, "Pump:1") == []
    with ServerProcess(db) as server, httpx.Client(base_url=server.url, timeout=30) as client:
        assert levels(client, "Tank:1") == []
        assert levels(client, "Pump:1") == []
        assert levels(client, "Tank:2") == expected(range(10))


def test_deletes_survive_sigkill_and_what_came_after_them_survives_too(tmp_path):
    db = tmp_path / "killed.duckdb"
    server = ServerProcess(db).start()
    with httpx.Client(base_url=server.url, timeout=30) as client:
        for v in range(10):
            notify(client, "Tank:1", "Tank", v)
            notify(client, "Pump:1", "Pump", v)
        delete(client, "/v2/entities/Tank:1")
        delete(client, "/v2/types/Pump")
    server.kill()  # the deleted samples' records are still in the log

    server = ServerProcess(db).start()
    with httpx.Client(base_url=server.url, timeout=30) as client:
        assert levels(client, "Tank:1") == [] and levels(client, "Pump:1") == []
        for v in range(10, 20):  # acknowledged after the delete: kept
            notify(client, "Tank:1", "Tank", v)
            notify(client, "Pump:2", "Pump", v)
        delete(client, "/v2/types/Pump")  # the newest records again
    server.kill()

    for _ in range(2):  # a kill while nothing happens, then a clean stop: the same history
        server = ServerProcess(db).start()
        with httpx.Client(base_url=server.url, timeout=30) as client:
            assert levels(client, "Tank:1") == expected(range(10, 20))
            assert levels(client, "Pump:1") == [] and levels(client, "Pump:2") == []
        server.kill()
    with ServerProcess(db) as server, httpx.Client(base_url=server.url, timeout=30) as client:
        assert levels(client, "Tank:1") == expected(range(10, 20))


def _speeds(client: httpx.Client, entity_id: str) -> list[dict]:
    answer = client.get(f"{LD}/{entity_id}", headers=LD_HEADERS)
    assert answer.status_code == 200, answer.text
    speed = answer.json()["speed"]
    return sorted(speed if isinstance(speed, list) else [speed], key=lambda i: i["observedAt"])


def test_ngsi_ld_instance_edits_survive_a_restart_and_a_kill(tmp_path):
    db = tmp_path / "instances.duckdb"
    vehicle = "urn:ngsi-ld:Vehicle:1"

    def speed(v: int) -> dict:
        return {"type": "Property", "value": v, "observedAt": f"2024-05-01T10:00:0{v}Z"}

    server = ServerProcess(db).start()
    with httpx.Client(base_url=server.url, timeout=30) as client:
        created = client.post(LD, json={"id": vehicle, "type": "Vehicle", "speed": [speed(1)]}, headers=LD_HEADERS)
        assert created.status_code == 201, created.text
        for v in (2, 3):  # each its own write: the newest holds the largest row id
            answer = client.post(f"{LD}/{vehicle}/attrs", json={"speed": [speed(v)]}, headers=LD_HEADERS)
            assert answer.status_code == 204, answer.text
        _, second, newest = (i["instanceId"] for i in _speeds(client, vehicle))
        answer = client.delete(f"{LD}/{vehicle}/attrs/speed/{newest}", headers=LD_HEADERS)
        assert answer.status_code == 204, answer.text
        patch = {"speed": {"type": "Property", "value": 20}}
        answer = client.patch(f"{LD}/{vehicle}/attrs/speed/{second}", json=patch, headers=LD_HEADERS)
        assert answer.status_code == 204, answer.text
        after_edits = [(i["value"], i["observedAt"]) for i in _speeds(client, vehicle)]
    assert [value for value, _ in after_edits] == [1, 20]
    server.kill()
    server = ServerProcess(db).start()
    with httpx.Client(base_url=server.url, timeout=30) as client:
        assert [(i["value"], i["observedAt"]) for i in _speeds(client, vehicle)] == after_edits
    server.terminate()
    with ServerProcess(db) as server, httpx.Client(base_url=server.url, timeout=30) as client:
        assert [(i["value"], i["observedAt"]) for i in _speeds(client, vehicle)] == after_edits


def test_what_retention_deleted_stays_deleted_after_a_restart(tmp_path):
    db = tmp_path / "retained.duckdb"
    retention = {"TSDB_RETENTION": f"{TENANT}/Tank=30d", "TSDB_RETENTION_INTERVAL": "0.2"}
    with ServerProcess(db, extra_env=retention) as server, httpx.Client(base_url=server.url, timeout=30) as client:
        for v in range(10):  # May 2024: long past the 30 days kept
            notify(client, "Tank:1", "Tank", v)
        deadline = time.monotonic() + 30
        while levels(client, "Tank:1"):
            assert time.monotonic() < deadline, "retention never deleted the samples"
            time.sleep(0.05)
    with ServerProcess(db) as server, httpx.Client(base_url=server.url, timeout=30) as client:
        assert levels(client, "Tank:1") == []
