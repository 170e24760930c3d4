"""Geo ``lastN`` answered from tails loaded together (issue 15).

On DuckDB a newest-first read under a geo mask loads the in-memory tails of
the matched series it misses in one statement and answers from them where
they provably hold the newest matching samples (tsdb_service/storage/duckdb/
querier.py, ``_masked_rows``), so asking again reads no samples. The answer
must be the one the database gives: the same query asked twice, between new
notifications, late ones and deletes, always equals the model of
tests/support/geo_model.py, with tails far smaller than the series (most answers
cannot come from them) and larger (most can). PostgreSQL answers the same
from its index; both backends run it.
"""

from __future__ import annotations

import random

import pytest

from tests.support.geo_model import QUERIES, drive, got_rows


@pytest.mark.parametrize("rows", [3, 64])
def test_repeated_geo_lastn_equals_the_model(client_factory, store_url_factory, monkeypatch, rows):
    # Tracks of positions as small as the tails: windows they can and cannot answer.
    monkeypatch.setattr("tsdb_service.storage.duckdb.latest_geo.TRACK_ROWS", rows)
    with client_factory(store_url_factory(f"geo_tails_{rows}"), tail_cache_rows=rows) as client:
        drive(client, random.Random(1500 + rows), 260)


def test_a_repeated_query_answers_the_same(client_factory, store_url_factory):
    """Once from the database (loading the tails), then from memory."""
    with client_factory(store_url_factory("geo_tails_again"), tail_cache_rows=8) as client:
        drive(client, random.Random(15), 120)
        for geo, _ in QUERIES.values():
            for params in ({"lastN": 3}, {"lastN": 8}, {"lastN": 9}, {"limit": 4, "offset": 2}):
                assert got_rows(client, geo, params) == got_rows(client, geo, params), (geo, params)


BOX = "georel=coveredBy&geometry=box&coords=40.40,-3.72;40.43,-3.69"
NEAR = "georel=near;maxDistance:1500&geometry=point&coords=40.4168,-3.7038"
FLEET = {"Content-Type": "application/json", "Fiware-Service": "fleet"}


def _move(client, robot: int, step: int, t: int, rnd: random.Random) -> None:
    lon, lat = -3.74 + rnd.random() * 0.08, 40.38 + rnd.random() * 0.08
    where = {"type": "geo:json", "value": {"type": "Point", "coordinates": [lon, lat]}}
    if rnd.random() < 0.2:  # an area now and then: its text is kept, not only its box
        where = {"type": "geo:box", "value": [f"{lat}, {lon}", f"{lat + 0.002}, {lon + 0.003}"]}
    entity = {
        "id": f"Bot{robot}",
        "type": "Robot",
        "battery": {"type": "Number", "value": step},
        "TimeInstant": {"type": "DateTime", "value": f"2024-05-01T10:{t // 60:02d}:{t % 60:02d}Z"},
    }
    if rnd.random() < 0.8:  # some readings keep the previous location
        entity["location"] = where
    assert client.post("/v2/notify", json={"data": [entity]}, headers=FLEET).status_code == 200


def _history(client, query: str) -> object:
    response = client.get(f"/v2/types/Robot/attrs/battery?{query}", headers=FLEET)
    assert response.status_code == 200, response.text
    return response.json()


def test_positions_from_memory_agree_with_the_database(client_factory, store_url_factory, monkeypatch):
    """DuckDB reads positions from the tracks memory keeps (tiny ones here,
    so series outgrow them) where they answer; with them switched off it
    asks the database. Moves, late samples and deletes interleave, windows
    start before, inside and after the tracks; both answers always agree."""
    from tsdb_service.storage.duckdb.latest_geo import LatestGeo

    monkeypatch.setattr("tsdb_service.storage.duckdb.latest_geo.TRACK_ROWS", 15)
    monkeypatch.setattr("tsdb_service.storage.duckdb.latest_geo.TRACK_TOTAL", 40)
    rnd = random.Random(31)
    with client_factory(store_url_factory("geo_positions"), tail_cache_rows=4) as client:
        for step in range(240):
            roll = rnd.random()
            if roll < 0.65:
                t = step if rnd.random() < 0.85 else rnd.randint(0, step)
                _move(client, rnd.randint(0, 5), step, t, rnd)
            elif roll < 0.7:
                start = rnd.randint(0, step)
                client.delete(
                    f"/v2/entities/Bot{rnd.randint(0, 5)}",
                    headers=FLEET,
                    params={
                        "type": "Robot",
                        "fromDate": f"2024-05-01T10:{start // 60:02d}:{start % 60:02d}Z",
                        "toDate": "2024-05-01T10:59:59Z",
                    },
                )
            else:
                geo = rnd.choice((BOX, NEAR))
                page = rnd.choice(("lastN=3", "lastN=20", "limit=5&offset=2"))
                if rnd.random() < 0.5:
                    since = rnd.randint(0, step)
                    page += f"&fromDate=2024-05-01T10:{since // 60:02d}:{since % 60:02d}Z"
                if rnd.random() < 0.3:
                    until = rnd.randint(0, step + 5)
                    page += f"&toDate=2024-05-01T10:{until // 60:02d}:{until % 60:02d}Z"
                memory = _history(client, f"{geo}&{page}")
                with monkeypatch.context() as off:
                    off.setattr(LatestGeo, "positions", lambda self, sids, start, load: None)
                    database = _history(client, f"{geo}&{page}")
                assert memory == database, (step, geo, page)
