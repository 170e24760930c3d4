"""Sample semantics against an oracle: random robots, random geo-queries.

Robots wander around Madrid (two stay inside the queried areas); some
notifications carry a location, some
only a reading, some share a time index, some arrive late, and some of the
history is deleted. Every answer must equal what a plain Python model
computes: a reading matches when the robot's location as of that reading
(latest location by (time, arrival)) matches, then windows, lastN,
limit/offset and aggregation apply to the matching readings. On DuckDB
the tails are small, so both the in-memory and the SQL paths answer.
"""

from __future__ import annotations

import random
from collections import defaultdict

import pytest

from tests.support.geo_model import QUERIES, H, Model, drive, post_reading


def test_answers_equal_the_model(client_factory, store_url_factory):
    # Small tails: lastN of up to 12 over 16 cached rows, so some answers come
    # from memory and some cannot (too few matching rows cached).
    with client_factory(store_url_factory("geo_samples"), tail_cache_rows=16) as client:
        drive(client, random.Random(2024), 320)


def test_one_scan_for_many_series(client_factory, store_url_factory, store_url, monkeypatch):
    """PostgreSQL finds the candidates of thousands of series by box in
    ``geo_extents`` (GiST) instead of ``sid = ANY``: force that path."""
    if not store_url.startswith("postgresql"):
        pytest.skip("PostgreSQL only")
    monkeypatch.setattr("tsdb_service.storage.postgres.querier.MANY_SIDS", 0)
    with client_factory(store_url_factory("geo_samples_scan")) as client:
        drive(client, random.Random(77), 150)


@pytest.mark.parametrize("method", ["count", "sum", "max"])
def test_aggregations_equal_the_model(client_factory, store_url_factory, method):
    rnd = random.Random(7)
    model = Model()
    with client_factory(store_url_factory("geo_samples_aggr")) as client:
        for step in range(60):
            robot = f"R{rnd.randint(0, 2)}"
            location = None
            if rnd.random() < 0.5:
                location = (round(40.39 + rnd.random() * 0.05, 6), round(-3.73 + rnd.random() * 0.05, 6))
            post_reading(client, robot, step * 7, location, float(step))
            model.add(step * 7, robot, location, float(step))
        geo, inside = QUERIES["box"]
        response = client.get(f"/v2/types/Robot/attrs/speed?{geo}&aggrMethod={method}&aggrPeriod=minute", headers=H)
        assert response.status_code == 200, response.text
        got = {e["id"]: dict(zip(e["index"], e["values"], strict=True)) for e in response.json()["entities"]}
        expected: dict[str, dict] = defaultdict(lambda: defaultdict(list))
        for t, _k, robot, _loc, reading in model.matching(inside, 0, 10**9):
            expected[robot][f"2024-05-01T10:{t // 60:02d}:00.000+00:00"].append(reading)
        fold = {"count": len, "sum": sum, "max": max}[method]
        assert got == {robot: {minute: fold(v) for minute, v in per.items()} for robot, per in expected.items()}
