"""An empty ``GET /v2/entities`` says where the data is.

A new user's first request has no ``Fiware-Service`` header, and the demo
(and most brokers) store everything under tenants (``lawnmower``,
``warehouse``, ``drone``): the answer was ``[]`` and nothing more. The body
stays QuantumLeap's ``[]``; the ``X-Tsdb-Hint`` header names the tenants
that hold data, only those the caller's credential may touch.
"""

from __future__ import annotations

from tests.support.notify import post_notification
from tsdb_service.faces.quantumleap import openapi as oa


def note(eid: str) -> dict:
    return {"data": [{"id": eid, "type": "Robot", "battery": {"type": "Number", "value": 80}}]}


def _feed(client, headers=None) -> None:
    for tenant in ("lawnmower", "warehouse", "drone"):
        post_notification(client, note(f"{tenant}-1"), {"Fiware-Service": tenant, **(headers or {})})


def test_no_tenant_header_is_told_which_tenants_hold_data(client):
    _feed(client)
    answer = client.get("/v2/entities")
    assert answer.status_code == 200 and answer.json() == []
    assert answer.headers["X-Tsdb-Hint"] == (
        "the default tenant (no Fiware-Service) holds no data; tenants with data: drone, lawnmower, warehouse "
        "(send Fiware-Service: TENANT)"
    )


def test_a_mistyped_tenant_is_told_too(client):
    _feed(client)
    answer = client.get("/v2/entities", headers={"Fiware-Service": "lawnmover"})
    assert answer.json() == []
    assert "tenant 'lawnmover' holds no data; tenants with data: drone, lawnmower" in answer.headers["X-Tsdb-Hint"]


def test_no_hint_when_there_is_nothing_to_say(client):
    assert "X-Tsdb-Hint" not in client.get("/v2/entities").headers  # nothing stored anywhere
    _feed(client)
    found = client.get("/v2/entities", headers={"Fiware-Service": "drone"})
    assert [e["id"] for e in found.json()] == ["drone-1"] and "X-Tsdb-Hint" not in found.headers
    # A tenant that has data but nothing in this window: the tenant is right, the hint would mislead.
    later = client.get("/v2/entities", params={"fromDate": "2999-01-01T00:00:00Z"}, headers={"Fiware-Service": "drone"})
    assert later.json() == [] and "X-Tsdb-Hint" not in later.headers


def test_the_hint_names_only_tenants_the_credential_may_touch(client_factory, tmp_path):
    reader, writer = "reader-key-0123456789", "writer-key-0123456789"
    keys = f"{reader}:read:-,drone {writer}:admin"
    with client_factory(str(tmp_path / "db.duckdb"), api_keys=keys) as client:
        _feed(client, {"X-Api-Key": writer})
        answer = client.get("/v2/entities", headers={"X-Api-Key": reader})
        assert answer.status_code == 200 and answer.json() == []
        assert "tenants with data: drone (send" in answer.headers["X-Tsdb-Hint"]


def test_the_header_is_in_the_api_description(client):
    listed = client.get("/openapi.json").json()["paths"]["/v2/entities"]["get"]["responses"]["200"]
    assert listed["headers"] == oa.HINT
