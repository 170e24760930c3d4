"""``tsdb-service copy`` moves all history between backends and verifies it.

History copied DuckDB → PostgreSQL → DuckDB answers every query exactly as
the original does, and the rejected store and 'values' layouts come along.
"""

from __future__ import annotations

from tsdb_service.cli import main

H = {"Content-Type": "application/json", "Fiware-Service": "copyland", "Fiware-ServicePath": "/site/a"}
QUERIES = [
    "/v2/entities",
    "/v2/entities/Mower:1",
    "/v2/entities/Mower:1/attrs/odom(twist.twist.linear.x)?lastN=3",
    "/v2/types/Mower/attrs/battery?aggrMethod=avg&aggrPeriod=minute",
    "/v2/entities?georel=near;maxDistance:500&geometry=point&coords=40.4168,-3.7038",
]


def _notification(i: int) -> dict:
    return {"subscriptionId": "s", "data": [{
        "id": f"Mower:{i % 2}", "type": "Mower",
        "battery": {"type": "Number", "value": 90 - i},
        "mode": {"type": "Text", "value": "mowing" if i % 3 else "docked"},
        "odom": {"type": "Object", "value": {"twist": {"twist": {"linear": {"x": i / 10}}}}},
        "location": {"type": "geo:point", "value": f"40.4168, -3.70{i % 10}"},
        "TimeInstant": {"type": "DateTime", "value": f"2024-05-01T10:{i // 60:02d}:{i % 60:02d}.250Z"},
    }]}


def _answers(client) -> list:
    return [(q, client.get(q, headers=H).status_code, client.get(q, headers=H).json()) for q in QUERIES]


def test_copy_round_trip_keeps_every_answer(tmp_path, pg_cluster, client_factory, capsys):
    original = str(tmp_path / "original.duckdb")
    with client_factory(original) as client:
        for i in range(40):
            assert client.post("/v2/notify", json=_notification(i), headers=H).status_code == 200
        assert client.post("/v2/notify", content=b"{broken", headers=H).status_code == 400
        client.put("/v2/notify/subscriptions/sub-1", json={"attrs": ["id", "battery"]}, headers=H)
        expected = _answers(client)
    assert all(status == 200 for _, status, _ in expected)

    pg_url = pg_cluster.database("copy_target")
    assert main(["copy", "--from", original, "--to", pg_url, "--quiet"]) == 0
    back = str(tmp_path / "back.duckdb")
    assert main(["copy", "--from", pg_url, "--to", back, "--quiet"]) == 0
    assert "copy verified" in capsys.readouterr().out

    for url in (pg_url, back):
        with client_factory(url) as client:
            assert _answers(client) == expected, url
            rejected = client.get("/v2/notify/rejected", headers=H).json()
            assert [r["body"] for r in rejected] == ["{broken"]
            assert client.get("/v2/notify/subscriptions", headers=H).json()["sub-1"]["attrs"] == ["id", "battery"]


def test_copy_refuses_the_same_store(tmp_path):
    same = str(tmp_path / "x.duckdb")
    assert main(["copy", "--from", same, "--to", same]) == 2

