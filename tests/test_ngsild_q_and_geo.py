"""A type-level query with both ``q`` and a geo-query: the geo-query finds
the entities from the types' location series alone (``Fetcher.located``:
stored extents, then the exact test), ``q`` is judged on those. The answer
must be the entities both hold for, each judged over the instances in the
window, whatever each alone would select. On both backends."""

from __future__ import annotations

import math

import pytest

from tests.ngsild_fixtures import get, ids, ld_notify

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


@pytest.fixture(scope="module")
def robots(client_factory, store_url_factory):
    """One store per backend holding the robots; the tests only read it."""
    with client_factory(store_url_factory("robots")) as client:
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
        yield client


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


# -- a crowd: enough series that DuckDB answers the geo-query and q in one scan ---------
#
# Over more than a few dozen series (``duckdb.querier.PER_SERIES_BRANCHES``)
# DuckDB reads the locations and each ``q`` term the database decides in one
# statement (``Querier.window_scan``); the answer must stay the intersection.

CROWD = 60


def crowd_robot(n: int, side: int) -> dict:
    """Robot ``n`` at ``side`` 0 (early) or 1 (late): a spiral around the
    centre, every fifth one moving, speeds and names that vary with ``n``."""
    moves = n % 5 == 0
    radius = 0.0005 * (n + (40 * side if moves else 0))
    angle = n * 2.4
    at = [CENTRE[0] + radius * math.cos(angle), CENTRE[1] + radius * math.sin(angle)]
    return {
        "id": robot_id(f"crowd-{n:03d}"),
        "type": "Robot",
        "speed": {"type": "Property", "value": (n * 7 + side * 3) % 10, "observedAt": (EARLY, LATE)[side]},
        "name": {"type": "Property", "value": f"r{n % 4}", "observedAt": (EARLY, LATE)[side]},
        "location": {
            "type": "GeoProperty",
            "observedAt": (EARLY, LATE)[side],
            "value": {"type": "Point", "coordinates": at},
        },
    }


@pytest.fixture(scope="module")
def crowd(client_factory, store_url_factory):
    """One store per backend holding the crowd; the tests only read it."""
    with client_factory(store_url_factory("crowd")) as client:
        for side in (0, 1):
            ld_notify(client, [crowd_robot(n, side) for n in range(CROWD)])
        yield client


@pytest.mark.parametrize("geo", [NEAR, AWAY, WITHIN, DISJOINT], ids=["near", "min-distance", "within", "disjoint"])
@pytest.mark.parametrize(
    "q",
    ["speed>=5", "speed>=5;speed<8", 'speed<3|name=="r1"', 'speed>=4;name~="r[02]"', "speed>100"],
    ids=["one-term", "two-terms", "or-text", "regex-in-python", "none"],
)
@pytest.mark.parametrize("window", [{}, EARLY_ONLY], ids=["all", "early"])
def test_a_crowd_is_still_the_intersection(crowd, geo, q, window):
    base = {"type": "Robot", "attrs": "speed", "limit": "100", **window}
    by_q = set(ids(get(crowd, {**base, "q": q})))
    by_geo = set(ids(get(crowd, {**base, **geo})))
    both = get(crowd, {**base, "q": q, **geo, "count": "true"})
    assert ids(both) == sorted(by_q & by_geo)
    assert both.headers["NGSILD-Results-Count"] == str(len(by_q & by_geo))
    assert 0 < len(by_geo) < CROWD or geo is DISJOINT  # the geo-query does split the crowd
