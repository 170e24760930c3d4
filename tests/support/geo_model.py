"""Robots wandering around Madrid, and a plain Python model of what the
geo-queries over their history must answer.

``drive`` sends random notifications (some with a location, some sharing a
time index, some late), deletes and geo-queries, and checks each answer
against ``Model``: a reading matches when the robot's location as of that
reading lies in the queried area; lastN, limit/offset and aggregation apply
to the matching readings. ``QUERIES`` are the two areas (a box, a circle).
"""

from __future__ import annotations

import random
from collections import defaultdict

from pyproj import Geod

H = {"Content-Type": "application/json", "Fiware-Service": "geosamples"}


WGS84 = Geod(ellps="WGS84")


ROBOTS = 5


BOX = (40.40, -3.72, 40.43, -3.69)  # lat, lon, lat, lon


NEAR = ((40.415, -3.705), 2500)  # (lat, lon), metres


def iso(t: int) -> str:
    return f"2024-05-01T10:{t // 60:02d}:{t % 60:02d}"


class Model:
    """What was stored, as (t, arrival, robot, location or None, reading)."""

    def __init__(self) -> None:
        self.rows: list[tuple[int, int, str, tuple[float, float] | None, float]] = []
        self.arrived = 0

    def add(self, t, robot, location, reading) -> None:
        self.arrived += 1
        self.rows.append((t, self.arrived, robot, location, reading))

    def holds(self, robot, start, end) -> bool:
        """Whether a delete of ``robot`` over [start, end] finds samples (204) or not (404)."""
        return any(r[2] == robot and start <= r[0] <= end for r in self.rows)

    def delete(self, robot, start, end) -> None:
        self.rows = [r for r in self.rows if not (r[2] == robot and start <= r[0] <= end)]

    def matching(self, inside, start, end) -> list[tuple]:
        """Readings in [start, end] taken where ``inside`` holds, by (t, arrival)."""
        out = []
        by_robot = defaultdict(list)
        for row in sorted(self.rows):
            by_robot[row[2]].append(row)
        for rows in by_robot.values():
            where = None
            for row in rows:
                if row[3] is not None:
                    where = row[3]
                if start <= row[0] <= end and where is not None and inside(where):
                    out.append(row)
        return sorted(out)


def in_box(where) -> bool:
    lat, lon = where
    return BOX[0] <= lat <= BOX[2] and BOX[1] <= lon <= BOX[3]


def near(where) -> bool:
    (clat, clon), metres = NEAR
    return WGS84.inv(clon, clat, where[1], where[0])[2] <= metres


QUERIES = {
    "box": (f"georel=coveredBy&geometry=box&coords={BOX[0]},{BOX[1]};{BOX[2]},{BOX[3]}", in_box),
    "near": (f"georel=near;maxDistance:{NEAR[1]}&geometry=point&coords={NEAR[0][0]},{NEAR[0][1]}", near),
}


def post_reading(client, robot: str, t: int, location, reading: float) -> None:
    entity = {
        "id": robot,
        "type": "Robot",
        "TimeInstant": {"type": "DateTime", "value": iso(t) + "Z"},
        "speed": {"type": "Number", "value": reading},
    }
    if location is not None:
        entity["location"] = {"type": "geo:json", "value": {"type": "Point", "coordinates": [location[1], location[0]]}}
    assert client.post("/v2/notify", json={"data": [entity]}, headers=H).status_code == 200


def expected_rows(model: Model, inside, params: dict) -> dict[str, list]:
    start = params.get("from", 0)
    end = params.get("to", 10**9)
    rows = model.matching(inside, start, end)
    if "lastN" in params:
        rows = rows[max(0, len(rows) - params["lastN"]) :]
    else:
        rows = rows[params.get("offset", 0) : params.get("offset", 0) + params.get("limit", 10**9)]
    out: dict[str, list] = defaultdict(list)
    for t, _k, robot, _loc, reading in rows:
        out[robot].append((iso(t) + ".000+00:00", reading))
    return dict(out)


def got_rows(client, geo: str, params: dict) -> dict[str, list]:
    query = [geo]
    for name, key in (("fromDate", "from"), ("toDate", "to")):
        if key in params:
            query.append(f"{name}={iso(params[key])}Z")
    query += [f"{k}={params[k]}" for k in ("lastN", "limit", "offset") if k in params]
    response = client.get("/v2/types/Robot/attrs/speed?" + "&".join(query), headers=H)
    assert response.status_code == 200, response.text
    body = response.json()
    entities = [] if body == [] else body["entities"]
    return {e["id"]: list(zip(e["index"], e["values"], strict=True)) for e in entities}


def somewhere(rnd: random.Random, robot: str) -> tuple[float, float]:
    """Robots R0..R4 roam in and out of both query areas; the last two work
    well inside both (their whole extent matches: decided without reading
    their positions, until a delete makes their first position unknown)."""
    if int(robot[1:]) >= ROBOTS:
        return (round(40.415 + rnd.uniform(-0.001, 0.001), 6), round(-3.705 + rnd.uniform(-0.001, 0.001), 6))
    return (round(40.39 + rnd.random() * 0.05, 6), round(-3.73 + rnd.random() * 0.05, 6))


def random_params(rnd: random.Random, now: int) -> dict:
    params: dict = {}
    if rnd.random() < 0.3:
        params["from"] = rnd.randint(0, now)
    if rnd.random() < 0.3:
        params["to"] = rnd.randint(params.get("from", 0), now + 5)
    roll = rnd.random()
    if roll < 0.5:
        params["lastN"] = rnd.randint(1, 12)
    elif roll < 0.8:
        params["limit"] = rnd.randint(1, 12)
        params["offset"] = rnd.randint(0, 6)
    return params


def drive(client, rnd: random.Random, steps: int) -> None:
    """``steps`` random notifications, deletes and queries, each query's
    answer checked against the model."""
    model = Model()
    now = 0
    for step in range(steps):
        roll = rnd.random()
        if roll < 0.75:
            now += rnd.choice((0, 1, 1, 2))  # some time indexes shared
            t = now if rnd.random() < 0.9 else rnd.randint(max(0, now - 30), now)  # some late
            robot = f"R{rnd.randint(0, ROBOTS + 1)}"
            location = None
            if rnd.random() < 0.6:
                location = somewhere(rnd, robot)
            reading = float(step)
            post_reading(client, robot, t, location, reading)
            model.add(t, robot, location, reading)
        elif roll < 0.78:
            robot, start = f"R{rnd.randint(0, ROBOTS + 1)}", rnd.randint(0, now)
            end = start + rnd.randint(0, 20)
            response = client.delete(
                f"/v2/entities/{robot}",
                headers=H,
                params={"type": "Robot", "fromDate": iso(start) + "Z", "toDate": iso(end) + "Z"},
            )
            assert response.status_code == (204 if model.holds(robot, start, end) else 404), response.text
            model.delete(robot, start, end)
        else:
            if step % 3 == 0:  # a plain lastN loads the tails a geo-query may then answer from
                assert client.get("/v2/types/Robot/attrs/speed?lastN=5", headers=H).status_code == 200
            name = rnd.choice(list(QUERIES))
            geo, inside = QUERIES[name]
            params = random_params(rnd, now)
            assert got_rows(client, geo, params) == expected_rows(model, inside, params), (step, name, params)
