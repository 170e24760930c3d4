"""Moving entities: what a geo-query keeps over time (issues 4 and 10).

Default, sample semantics (QuantumLeap's; tsdb_service/history/geo_matching.py): a
stored sample matches when the location its entity had at that sample's
time matches: the latest location sample at or before it by (time, row id),
so a notification's own location counts for its other attributes and a
notification without one keeps the previous. ``lastN``, ``limit``,
``offset`` and aggregations apply to the matching samples.

``geoScope=entity``: an entity matches when its *latest* location does (at
or before ``toDate`` when given); its whole history is then returned.

The scene, in Barcelona (notifications every 10 minutes, TimeInstant):

* ``robot-1`` drives from outside the port area AREA (t0) through it (t1,
  t2), leaves it (t3) and ends at Plaça de Catalunya (t4);
* ``robot-2`` is parked inside AREA: one location at t0, later notifications
  (t2, t4) carry no location;
* ``robot-3`` stays far away;
* ``drone-1`` has no ``location``: its geo attributes are ``gps`` (inside
  AREA only at t0, at Plaça de Catalunya from t1) and ``home`` (always at
  Plaça de Catalunya); ``gps`` is first by name, so it is the location;
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
ENTITY = "geoScope=entity"

ROBOT_1_PATH = ["41.3650, 2.1600", "41.3720, 2.1740", "41.3760, 2.1800", "41.3840, 2.1900", "41.3874, 2.1686"]
ROBOT_1_INSIDE = [False, True, True, False, False]
PARKED = "41.3750, 2.1780"
OUTSIDE = "41.3900, 2.1000"


def _note(eid: str, etype: str, t: str, **attrs) -> dict:
    return {
        "subscriptionId": "geo-moving",
        "data": [{"id": eid, "type": etype, "TimeInstant": {"type": "DateTime", "value": t}, **attrs}],
    }


def _point(text: str | None) -> dict:
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
            notify(
                client,
                _note(
                    "drone-1",
                    "Drone",
                    t,
                    gps=_point(PARKED if i == 0 else ROBOT_1_PATH[4]),
                    home=_point("41.3874, 2.1686"),
                    altitude=_number(100 + i),
                ),
            )
        notify(
            client, _note("drone-2", "Drone", T[0], location=_point(OUTSIDE), aaa=_point(PARKED), altitude=_number(50))
        )
        _rovers(client, notify)
        yield client


def _rovers(client, notify) -> None:
    """Notifications sharing a time index: arrival order decides.

    rover-1: t0 inside (40); at t1 a reading without location (41) arrives
    before the notification that moves it outside (42).
    rover-2: t0 outside (50); at t1 a reading (53) arrives before the move
    inside (51), another (52) after it.
    rover-3: t0 inside (60); at t1 its location is null (61): not a
    position, the previous one stays."""
    send = lambda eid, t, **attrs: notify(client, _note(eid, "Rover", t, **attrs))  # noqa: E731
    send("rover-1", T[0], location=_point(PARKED), temperature=_number(40))
    send("rover-1", T[1], temperature=_number(41))
    send("rover-1", T[1], location=_point(OUTSIDE), temperature=_number(42))
    send("rover-2", T[0], location=_point(OUTSIDE), temperature=_number(50))
    send("rover-2", T[1], temperature=_number(53))
    send("rover-2", T[1], location=_point(PARKED), temperature=_number(51))
    send("rover-2", T[1], temperature=_number(52))
    send("rover-3", T[0], location=_point(PARKED), temperature=_number(60))
    send("rover-3", T[1], location={"type": "geo:json", "value": None}, temperature=_number(61))


def get(client, path: str):
    response = client.get(path)
    assert response.status_code == 200, response.text
    return response.json()


def ids(client, path: str) -> set[str]:
    body = get(client, path)
    if isinstance(body, list):  # /v2/entities, or an empty history
        return {e["id"] for e in body}
    return {e["id"] for e in body["entities"]}


def test_scene_geometry():
    """The path really enters and leaves AREA (lat 41.370..41.380, lon 2.170..2.185)."""
    for text, inside in zip(ROBOT_1_PATH, ROBOT_1_INSIDE, strict=True):
        lat, lon = (float(x) for x in text.split(","))
        assert (41.370 <= lat <= 41.380 and 2.170 <= lon <= 2.185) == inside, text


# --- sample semantics (default) ---------------------------------------------------------------


def test_a_robot_that_left_keeps_its_samples_inside(moving):
    """robot-1 drove through AREA and left: its readings taken inside."""
    assert get(moving, f"/v2/entities/robot-1/attrs/temperature?{AREA}") == {
        "id": "robot-1",
        "type": "Robot",
        "attrName": "temperature",
        "index": IDX[1:3],
        "values": [31.0, 32.0],
    }
    assert get(moving, f"/v2/entities/robot-1/attrs/location?{AREA}")["values"] == ROBOT_1_PATH[1:3]


def test_samples_without_location_use_the_previous_one(moving):
    """robot-2's only location is from t0: its later readings were taken there."""
    assert get(moving, f"/v2/types/Robot/attrs/temperature?{AREA}") == {
        "type": "Robot",
        "attrName": "temperature",
        "entities": [
            {"id": "robot-1", "index": IDX[1:3], "values": [31.0, 32.0]},
            {"id": "robot-2", "index": [IDX[0], IDX[2], IDX[4]], "values": [20.0, 21.0, 22.0]},
        ],
    }


def test_entities_list_every_entity_with_a_matching_sample(moving):
    """The index is the entity's latest matching sample."""
    found = {e["id"]: e["index"] for e in get(moving, f"/v2/entities?{AREA}")}
    assert found == {
        "robot-1": IDX[2],
        "robot-2": IDX[4],
        "drone-1": IDX[0],
        "rover-1": IDX[1],
        "rover-2": IDX[1],
        "rover-3": IDX[1],
    }
    assert ids(moving, f"/v2/entities?type=Robot&{PL_CATALUNYA}") == {"robot-1"}
    assert ids(moving, f"/v2/entities?{PL_CATALUNYA}") == {"robot-1", "drone-1"}


@pytest.mark.parametrize(
    ("to_date", "expected"),
    [
        pytest.param(f"{DAY}09:59:59Z", set(), id="before-any-sample"),
        pytest.param(T[0], {"robot-2", "drone-1"}, id="t0"),
        pytest.param(f"{DAY}10:05:00Z", {"robot-2", "drone-1"}, id="between-t0-t1"),
        pytest.param(T[1], {"robot-1", "robot-2", "drone-1"}, id="t1-robot-inside"),
        pytest.param(T[4], {"robot-1", "robot-2", "drone-1"}, id="t4-robot-left-long-ago"),
    ],
)
def test_toDate_bounds_the_samples(moving, to_date, expected):
    assert ids(moving, f"/v2/entities?type=Robot,Drone&{AREA}&toDate={to_date}") == expected


def test_location_before_fromDate_counts(moving):
    """fromDate=t2: robot-2's location (t0) is from before the window; its
    readings in the window were still taken inside."""
    assert get(moving, f"/v2/types/Robot/attrs/temperature?{AREA}&fromDate={T[2]}&toDate={T[4]}") == {
        "type": "Robot",
        "attrName": "temperature",
        "entities": [
            {"id": "robot-1", "index": [IDX[2]], "values": [32.0]},
            {"id": "robot-2", "index": [IDX[2], IDX[4]], "values": [21.0, 22.0]},
        ],
    }
    assert ids(moving, f"/v2/entities?type=Robot&{AREA}&fromDate={T[3]}") == {"robot-2"}


def test_lastN_counts_matching_samples(moving):
    """lastN applies after the filter: robot-1's newest samples (t3, t4) are
    outside, its newest matching one is t2."""
    assert get(moving, f"/v2/entities/robot-1/attrs/temperature?{AREA}&lastN=1") == {
        "id": "robot-1",
        "type": "Robot",
        "attrName": "temperature",
        "index": [IDX[2]],
        "values": [32.0],
    }
    assert get(moving, f"/v2/entities/robot-1/attrs/location?{PL_CATALUNYA}&lastN=3") == {
        "id": "robot-1",
        "type": "Robot",
        "attrName": "location",
        "index": [IDX[4]],
        "values": [ROBOT_1_PATH[4]],
    }


def test_lastN_across_entities(moving):
    """Newest first over the whole answer: robot-2 at t4 and t2, then robot-1
    at t2 (it arrived before robot-2's notification of the same time)."""
    assert get(moving, f"/v2/types/Robot/attrs/temperature?{AREA}&lastN=3") == {
        "type": "Robot",
        "attrName": "temperature",
        "entities": [
            {"id": "robot-1", "index": [IDX[2]], "values": [32.0]},
            {"id": "robot-2", "index": [IDX[2], IDX[4]], "values": [21.0, 22.0]},
        ],
    }


def test_limit_and_offset_count_matching_samples(moving):
    assert get(moving, f"/v2/entities/robot-1/attrs/temperature?{AREA}&offset=1&limit=1")["values"] == [32.0]
    body = get(moving, f"/v2/types/Robot/attrs/temperature?{AREA}&offset=1&limit=3")
    assert body["entities"] == [
        {"id": "robot-1", "index": IDX[1:3], "values": [31.0, 32.0]},
        {"id": "robot-2", "index": [IDX[2]], "values": [21.0]},
    ]


def test_every_attribute_of_an_entity(moving):
    """All attributes of the rows taken inside (one notification = one row)."""
    assert get(moving, f"/v2/entities/robot-1?{AREA}") == {
        "id": "robot-1",
        "type": "Robot",
        "index": IDX[1:3],
        "attributes": [
            {"attrName": "TimeInstant", "values": T[1:3]},
            {"attrName": "location", "values": ROBOT_1_PATH[1:3]},
            {"attrName": "temperature", "values": [31.0, 32.0]},
        ],
    }


@pytest.mark.parametrize(
    ("method", "robot_1", "robot_2"),
    [("avg", 31.5, 21.0), ("sum", 63.0, 63.0), ("max", 32.0, 22.0), ("count", 2, 3)],
)
def test_aggregation_over_matching_samples(moving, method, robot_1, robot_2):
    body = get(moving, f"/v2/types/Robot/attrs/temperature?{AREA}&aggrMethod={method}&aggrPeriod=hour")
    hour = f"{DAY}10:00:00.000+00:00"
    assert body["entities"] == [
        {"id": "robot-1", "index": [hour], "values": [robot_1]},
        {"id": "robot-2", "index": [hour], "values": [robot_2]},
    ]


def test_non_matching_entity_history_is_empty(moving):
    assert get(moving, f"/v2/entities/robot-3?{AREA}") == []
    assert get(moving, f"/v2/entities/robot-1/attrs/temperature?{AREA}&toDate={T[0]}") == []
    assert get(moving, f"/v2/entities/robot-1/attrs/temperature?{AREA}&fromDate={T[3]}") == []


def test_arrival_order_breaks_time_ties(moving):
    """Rows of the same time: a reading sees the locations that arrived before it."""
    rovers = get(moving, f"/v2/types/Rover/attrs/temperature?{AREA}")["entities"]
    assert rovers == [
        {"id": "rover-1", "index": IDX[:2], "values": [40.0, 41.0]},
        {"id": "rover-2", "index": [IDX[1], IDX[1]], "values": [51.0, 52.0]},
        {"id": "rover-3", "index": IDX[:2], "values": [60.0, 61.0]},
    ]


# --- which attribute is the location ------------------------------------------------------------


def test_first_geo_attribute_by_name_when_no_location(moving):
    """drone-1: gps (first by name) was in AREA at t0 only; home (always at
    Plaça de Catalunya) is not its location."""
    assert get(moving, f"/v2/entities/drone-1/attrs/altitude?{AREA}")["values"] == [100.0]
    assert get(moving, f"/v2/entities/drone-1/attrs/altitude?{PL_CATALUNYA}") == {
        "id": "drone-1",
        "type": "Drone",
        "attrName": "altitude",
        "index": IDX[1:],
        "values": [101.0, 102.0, 103.0, 104.0],
    }
    assert get(moving, f"/v2/entities/drone-1/attrs/altitude?{PL_CATALUNYA}&lastN=2")["values"] == [103.0, 104.0]


def test_location_wins_over_an_earlier_geo_attribute(moving):
    """drone-2: ``aaa`` (first by name) is in AREA, ``location`` is not."""
    assert "drone-2" not in ids(moving, f"/v2/entities?{AREA}")
    assert "drone-2" in ids(moving, "/v2/entities?georel=near;maxDistance:10&geometry=point&coords=41.3900,2.1000")


# --- entity semantics (geoScope=entity) ------------------------------------------------------------


def test_entity_scope_the_latest_location_decides(moving):
    """robot-1 drove through AREA and left: only the parked robot-2 matches."""
    assert ids(moving, f"/v2/entities?type=Robot,Drone&{AREA}&{ENTITY}") == {"robot-2"}
    assert ids(moving, f"/v2/types/Robot/attrs/temperature?{AREA}&{ENTITY}") == {"robot-2"}
    assert ids(moving, f"/v2/entities?type=Robot,Drone&{PL_CATALUNYA}&{ENTITY}") == {"robot-1", "drone-1"}


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
def test_entity_scope_toDate_picks_the_location_at_that_time(moving, to_date, expected):
    assert ids(moving, f"/v2/entities?type=Robot,Drone&{AREA}&toDate={to_date}&{ENTITY}") == expected


def test_entity_scope_returns_the_whole_history(moving):
    """robot-1 is near Plaça de Catalunya now: its latest 3 locations come
    back, though two of them are far from it."""
    assert get(moving, f"/v2/entities/robot-1/attrs/location?{PL_CATALUNYA}&lastN=3&{ENTITY}") == {
        "id": "robot-1",
        "type": "Robot",
        "attrName": "location",
        "index": IDX[2:],
        "values": ROBOT_1_PATH[2:],
    }
    assert get(moving, f"/v2/types/Robot/attrs/location?{AREA}&toDate={T[2]}&lastN=4&{ENTITY}") == {
        "type": "Robot",
        "attrName": "location",
        "entities": [
            {"id": "robot-1", "index": IDX[:3], "values": ROBOT_1_PATH[:3]},
            {"id": "robot-2", "index": [IDX[0]], "values": [PARKED]},
        ],
    }


def test_entity_scope_fallback_attribute(moving):
    assert ids(moving, f"/v2/types/Drone?{AREA}&{ENTITY}") == set()
    assert ids(moving, f"/v2/types/Drone?{AREA}&toDate={T[0]}&{ENTITY}") == {"drone-1"}
    assert ids(moving, f"/v2/types/Drone?{PL_CATALUNYA}&toDate={T[0]}&{ENTITY}") == set()  # home is there, gps not
    assert get(moving, f"/v2/entities/drone-1/attrs/altitude?{PL_CATALUNYA}&lastN=2&{ENTITY}")["values"] == [
        103.0,
        104.0,
    ]
