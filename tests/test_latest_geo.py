"""The in-memory latest-location index answers as the database does.

Geo-queries without ``toDate`` use each series' latest location kept in
memory (``geoScope=entity``) or its extent (sample semantics, to skip
entities that were never near); with a ``toDate`` far in the future the
same question goes to the sample tables. Moving robots, late samples and deletes interleave; both
answers must always agree (DuckDB keeps the index; PostgreSQL always asks
the database, and must agree too).
"""

from __future__ import annotations

import random

H = {"Content-Type": "application/json", "Fiware-Service": "fleet"}
AREA = {"georel": "coveredBy", "geometry": "box", "coords": "40.40,-3.72;40.43,-3.69"}
NEAR = {"georel": "near;maxDistance:1500", "geometry": "point", "coords": "40.4168,-3.7038"}


def _move(client, robot: int, step: int, t: int, rnd: random.Random) -> None:
    lon, lat = -3.74 + rnd.random() * 0.08, 40.38 + rnd.random() * 0.08
    body = {
        "data": [
            {
                "id": f"Bot{robot}",
                "type": "Robot",
                "location": {"type": "geo:json", "value": {"type": "Point", "coordinates": [lon, lat]}},
                "battery": {"type": "Number", "value": step},
                "TimeInstant": {"type": "DateTime", "value": f"2024-05-01T10:{t // 60:02d}:{t % 60:02d}Z"},
            }
        ]
    }
    assert client.post("/v2/notify", json=body, headers=H).status_code == 200


def _ids(client, params: dict) -> list[str]:
    # geoScope=entity asks for each entity's latest location (the index); the
    # default sample semantics use the extents kept next to it (a prefilter).
    response = client.get("/v2/entities", params={**params, "type": "Robot"}, headers=H)
    assert response.status_code == 200, response.text
    return sorted(e["id"] for e in response.json())


def test_index_and_database_agree(client):
    rnd = random.Random(11)
    for step in range(200):
        roll = rnd.random()
        if roll < 0.6:
            t = step if rnd.random() < 0.85 else rnd.randint(0, step)
            _move(client, rnd.randint(0, 5), step, t, rnd)
        elif roll < 0.65:
            client.delete(
                f"/v2/entities/Bot{rnd.randint(0, 5)}",
                headers=H,
                params={"type": "Robot", "fromDate": f"2024-05-01T10:0{rnd.randint(1, 3)}:00Z"},
            )
        else:
            for query in (AREA, NEAR, {**AREA, "geoScope": "entity"}, {**NEAR, "geoScope": "entity"}):
                memory = _ids(client, query)
                database = _ids(client, {**query, "toDate": "2100-01-01T00:00:00Z"})
                assert memory == database, (step, query)
