"""Moving entities: the time semantics of geo-queries (issue 4).

Chosen semantics (tsdb_service/geo/matching.py): an entity matches when its
*latest* location satisfies the relation: the latest at or before ``toDate``
when given, else the latest stored (``fromDate`` does not move it). The
matching entities' history is then returned as the other parameters ask, so
the filter selects entities, not samples: ``lastN`` returns a matching
entity's latest N samples even where it was somewhere else.

The scene, in Barcelona (notifications every 10 minutes, TimeInstant):

* ``robot-1`` drives from outside the port area AREA (t0) through it (t1,
  t2), leaves it (t3) and ends at Plaça de Catalunya (t4);
* ``robot-2`` is parked inside AREA: one location at t0, later notifications
  (t2, t4) carry no location;
* ``robot-3`` stays far away;
* ``drone-1`` has no ``location``: its geo attributes are ``gps`` (moves
  like robot-1 but is inside AREA only at t0) and ``home`` (always at Plaça de
  Catalunya); ``gps`` is first by name, so it is the location;
* ``drone-2`` has ``location`` (outside AREA) and ``aaa`` (inside AREA,
  first by name): ``location`` wins.
"""

from __future__ import annotations

import pytest

DAY = "2024-05-01T"
T = [f"{DAY}10:{m:02d}:00.000Z" for m in (0, 10, 20, 30, 40)]
IDX = [f"{DAY}10:{m:02d}:00.000+00:00" for m in (0, 10, 20, 30, 40)]

AREA = "georel=coveredBy&geometry=box&coords=41.370,2.170;41.380,2.185"  # Port Vell / Barceloneta
PL_CATALUNYA = "georel=near;maxDistance:200&geometry=point&coords=41.3874,2.1686"

ROBOT_1_PATH = ["41.3650, 2.1600", "41.3720, 2.1740", "41.3760, 2.1800", "41.3840, 2.1900", "41.3874, 2.1686"]
ROBOT_1_INSIDE = [False, True, True, False, False]
PARKED = "41.3750, 2.1780"


def _note(eid: str, etype: str, t: str, **attrs) -> dict:
    return {"subscriptionId": "geo-moving",
            "data": [{"id": eid, "type": etype, "TimeInstant": {"type": "DateTime", "value": t}, **attrs}]}


def _point(text: str) -> dict:
    return {"type": "geo:point", "value": text}


def _number(x: float) -> dict:
    return {"type": "Number", "value": x}


@pytest.fixture(scope="module")
def moving(client_factory, store_url_factory, notify):
    with client_factory(store_url_factory("geo-moving")) as client:
        for i, t in enumerate(T):
            notify(client, _note("robot-1", "Robot", t, location=_point(ROBOT_1_PATH[i]), temperature=_number(30 + i)))
            if i in (0, 2, 4):
                extra = {"location": _point(PARKED)} if i == 0 else {}
                notify(client, _note("robot-2", "Robot", t, temperature=_number(20 + i // 2), **extra))
            notify(client, _note("robot-3", "Robot", t, location=_point(f"41.40{i}0, 2.1000"), temperature=_number(10)))
            notify(client, _note("drone-1", "Drone", t, gps=_point(PARKED if i == 0 else ROBOT_1_PATH[4]),
                                 home=_point("41.3874, 2.1686"), altitude=_number(100 + i)))
        notify(client, _note("drone-2", "Drone", T[0], location=_point("41.3900, 2.1000"), aaa=_point(PARKED),
                             altitude=_number(50)))
        yield client


def ids(client, path: str) -> set[str]:
    response = client.get(path)
    assert response.status_code == 200, response.text
    body = response.json()
    if isinstance(body, list):  # /v2/entities, or an empty history
        return {e["id"] for e in body}
    return {e["id"] for e in body["entities"]}


def test_scene_geometry():
    """The path really enters and leaves AREA (lat 41.370..41.380, lon 2.170..2.185)."""
    for text, inside in zip(ROBOT_1_PATH, ROBOT_1_INSIDE, strict=True):
        lat, lon = (float(x) for x in text.split(","))
        assert (41.370 <= lat <= 41.380 and 2.170 <= lon <= 2.185) == inside, text


def test_without_toDate_the_latest_location_decides(moving):
    """robot-1 drove through AREA and left: only the parked robot-2 matches
    (its only location is from t0; later notifications without location keep it)."""
    assert ids(moving, f"/v2/entities?{AREA}") == {"robot-2"}
    assert ids(moving, f"/v2/types/Robot/attrs/temperature?{AREA}") == {"robot-2"}
    assert ids(moving, f"/v2/entities?{PL_CATALUNYA}") == {"robot-1", "drone-1"}


@pytest.mark.parametrize(
    ("to_date", "expected"),
    [
        pytest.param(f"{DAY}09:59:59Z", set(), id="before-any-sample"),
        pytest.param(T[0], {"robot-2", "drone-1"}, id="t0-drone-gps-inside"),
        pytest.param(T[1], {"robot-1", "robot-2"}, id="t1-robot-inside"),
        pytest.param(f"{DAY}10:15:00Z", {"robot-1", "robot-2"}, id="between-t1-t2"),
        pytest.param(T[2], {"robot-1", "robot-2"}, id="t2-robot-inside"),
        pytest.param(T[3], {"robot-2"}, id="t3-robot-left"),
    ],
)
def test_toDate_picks_the_location_at_that_time(moving, to_date, expected):
    assert ids(moving, f"/v2/entities?{AREA}&toDate={to_date}") == expected


def test_fromDate_does_not_move_the_location(moving):
    """fromDate alone: still the latest location (robot-1 has left)."""
    assert ids(moving, f"/v2/entities?{AREA}&fromDate={T[1]}") == {"robot-2"}


def test_location_before_fromDate_counts(moving):
    """fromDate=t1, toDate=t2: robot-2's latest location at or before t2 is
    from t0, before the window; it still matches, and its samples in the
    window are returned."""
    response = moving.get(f"/v2/types/Robot/attrs/temperature?{AREA}&fromDate={T[1]}&toDate={T[2]}")
    assert response.status_code == 200, response.text
    assert response.json() == {
        "type": "Robot", "attrName": "temperature", "entities": [
            {"id": "robot-1", "index": IDX[1:3], "values": [31.0, 32.0]},
            {"id": "robot-2", "index": [IDX[2]], "values": [21.0]},
        ]}


def test_lastN_returns_samples_outside_the_area(moving):
    """The filter selects entities, not samples: robot-1 is near Plaça de
    Catalunya now, and its latest 3 locations include two far from it (t2 is
    inside the port area, t3 east of it), returned raw."""
    response = moving.get(f"/v2/entities/robot-1/attrs/location?{PL_CATALUNYA}&lastN=3")
    assert response.status_code == 200, response.text
    assert response.json() == {
        "id": "robot-1", "type": "Robot", "attrName": "location", "index": IDX[2:], "values": ROBOT_1_PATH[2:]}


def test_lastN_with_toDate(moving):
    """At t2 both robots were in AREA. On a type, lastN counts rows of the
    whole answer, newest first (as QuantumLeap); lastN=4 up to t2 includes
    robot-1's t0 sample, taken outside AREA."""
    response = moving.get(f"/v2/types/Robot/attrs/location?{AREA}&toDate={T[2]}&lastN=4")
    assert response.status_code == 200, response.text
    assert response.json() == {
        "type": "Robot", "attrName": "location", "entities": [
            {"id": "robot-1", "index": IDX[:3], "values": ROBOT_1_PATH[:3]},
            {"id": "robot-2", "index": [IDX[0]], "values": [PARKED]},
        ]}


def test_lastN_across_entities(moving):
    response = moving.get(f"/v2/types/Robot/attrs/temperature?{AREA}&toDate={T[2]}&lastN=3")
    assert response.status_code == 200, response.text
    assert response.json() == {
        "type": "Robot", "attrName": "temperature", "entities": [
            {"id": "robot-1", "index": IDX[1:3], "values": [31.0, 32.0]},
            {"id": "robot-2", "index": [IDX[2]], "values": [21.0]},
        ]}


def test_non_matching_entity_history_is_empty(moving):
    assert moving.get(f"/v2/entities/robot-1?{AREA}").json() == []
    assert moving.get(f"/v2/entities/robot-3/attrs/temperature?{AREA}&toDate={T[2]}").json() == []


# --- which attribute is the location ----------------------------------------------------------


def test_first_geo_attribute_by_name_when_no_location(moving):
    """drone-1 has gps (first by name) and home. home is always at Plaça de
    Catalunya, gps is there from t1 on; at t0 gps was inside AREA."""
    assert ids(moving, f"/v2/types/Drone?{AREA}") == set()
    assert ids(moving, f"/v2/types/Drone?{AREA}&toDate={T[0]}") == {"drone-1"}
    assert ids(moving, f"/v2/types/Drone?{PL_CATALUNYA}") == {"drone-1"}
    assert ids(moving, f"/v2/types/Drone?{PL_CATALUNYA}&toDate={T[0]}") == set()  # home is there, gps is not


def test_location_wins_over_an_earlier_geo_attribute(moving):
    """drone-2: ``aaa`` (first by name) is in AREA, ``location`` is not."""
    assert "drone-2" not in ids(moving, f"/v2/entities?{AREA}")
    assert "drone-2" in ids(moving, "/v2/entities?georel=near;maxDistance:10&geometry=point&coords=41.3900,2.1000")


def test_fallback_attribute_history(moving):
    """The matched drone's other attributes come back as asked."""
    response = moving.get(f"/v2/entities/drone-1/attrs/altitude?{PL_CATALUNYA}&lastN=2")
    assert response.status_code == 200, response.text
    assert response.json() == {
        "id": "drone-1", "type": "Drone", "attrName": "altitude", "index": IDX[3:], "values": [103.0, 104.0]}
