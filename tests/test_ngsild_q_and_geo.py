"""A type-level query with both ``q`` and a geo-query: the geo-query finds
the entities from the types' location series alone (``Fetcher.located``:
stored extents, then the exact test), ``q`` is judged on those. The answer
must be the entities both hold for, each judged over the instances in the
window, whatever each alone would select. On both backends."""

from __future__ import annotations

import pytest
from ngsild_fixtures import get, ids, ld_notify

EARLY, LATE = "2024-01-01T00:00:00Z", "2024-01-01T01:00:00Z"
CENTRE = [0.03, 0.0]
NEAR = {"georel": "near;maxDistance==1500", "geometry": "Point", "coordinates": str(CENTRE)}
AWAY = {"georel": "near;minDistance==1500", "geometry": "Point", "coordinates": str(CENTRE)}
SQUARE = "[[[0.02, -0.01], [0.04, -0.01], [0.04, 0.01], [0.02, 0.01], [0.02, -0.01]]]"
WITHIN = {"georel": "within", "geometry": "Polygon", "coordinates": SQUARE}
DISJOINT = {"georel": "disjoint", "geometry": "Polygon", "coordinates": SQUARE}
EARLY_ONLY = {"timerel": "before", "timeAt": "2024-01-01T00:30:00Z"}
LATE_ONLY = {"timerel": "after", "timeAt": "2024-01-01T00:30:00Z"}

# robot: (early position, late position, early speed, late speed)
ROBOTS = {
    "inside": ([0.03, 0.0], [0.03, 0.0], 5, 5),
    "box-corner": ([0.042, 0.0105], [0.042, 0.0105], 5, 5),  # in the circle's box, ~1.8 km from its centre
    "slow-inside": ([0.031, 0.0], [0.031, 0.0], 1, 1),
    "fast-later": ([0.029, 0.001], [0.029, 0.001], 1, 7),
    "leaves": ([0.035, 0.0], [0.5, 0.0], 6, 6),
    "arrives": ([0.5, 0.0], [0.025, 0.0], 6, 6),
    "far": ([1.0, 1.0], [1.0, 1.0], 9, 9),
}


def robot_id(name: str) -> str:
    return f"urn:ngsi-ld:Robot:{name}"


@pytest.fixture
def robots(client):
    for at, side in ((EARLY, 0), (LATE, 1)):
        ld_notify(
            client,
            [
                {
                    "id": robot_id(name),
                    "type": "Robot",
                    "speed": {"type": "Property", "value": robot[2 + side], "observedAt": at},
                    "location": {
                        "type": "GeoProperty",
                        "observedAt": at,
                        "value": {"type": "Point", "coordinates": robot[side]},
                    },
                }
                for name, robot in ROBOTS.items()
            ],
        )
    return client


def test_q_and_near_hold_together(robots):
    found = get(robots, {"type": "Robot", "attrs": "speed", "q": "speed>=5", **NEAR})
    assert ids(found) == [robot_id(n) for n in ("arrives", "fast-later", "inside", "leaves")]


def test_each_is_judged_over_the_window(robots):
    early = get(robots, {"type": "Robot", "attrs": "speed", "q": "speed>=5", **NEAR, **EARLY_ONLY})
    assert ids(early) == [robot_id(n) for n in ("inside", "leaves")]
    late = get(robots, {"type": "Robot", "attrs": "speed", "q": "speed>=5", **NEAR, **LATE_ONLY})
    assert ids(late) == [robot_id(n) for n in ("arrives", "fast-later", "inside")]


@pytest.mark.parametrize("geo", [NEAR, AWAY, WITHIN, DISJOINT], ids=["near", "min-distance", "within", "disjoint"])
@pytest.mark.parametrize("q", ["speed>=5", "speed<5", "speed==6", "speed>100"])
@pytest.mark.parametrize("window", [{}, EARLY_ONLY, LATE_ONLY], ids=["all", "early", "late"])
def test_together_is_the_intersection_of_each_alone(robots, geo, q, window):
    base = {"type": "Robot", "attrs": "speed", **window}
    by_q = set(ids(get(robots, {**base, "q": q})))
    by_geo = set(ids(get(robots, {**base, **geo})))
    both = get(robots, {**base, "q": q, **geo, "count": "true"})
    assert ids(both) == sorted(by_q & by_geo)
    assert both.headers["NGSILD-Results-Count"] == str(len(by_q & by_geo))


def test_a_bad_q_is_refused_before_anything_runs_beside_it(robots):
    response = get(robots, {"type": "Robot", "q": "(speed>5", **NEAR}, status=400)
    assert response.json()["type"].endswith("BadRequestData")
