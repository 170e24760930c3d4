"""Random robot telemetry for the long-window tests, stored as a broker sends it.

Three robots over six hours, notified out of order (late samples), with
equal times in one series (two notifications of the same instant), equal
values (ties for the minimum and maximum), nulls, integers, floats, texts,
booleans and a ROS-like structured value, and an outage of one hour in the
middle (no sample at all: a gap). ``T0`` is the first hour.
"""

from __future__ import annotations

import random
from datetime import UTC, datetime, timedelta

T0 = datetime(2024, 5, 1, 10, 0, tzinfo=UTC)
HOURS = 6
OUTAGE = (T0 + timedelta(hours=3), T0 + timedelta(hours=4))  # no sample of any robot in [start, end)
TENANT = "longwin"
HEADERS = {"Fiware-Service": TENANT, "Fiware-ServicePath": "/"}
ROBOTS = ("urn:Robot:1", "urn:Robot:2", "urn:Robot:3")
MODES = ("idle", "mowing", "docked")


def _state(rng: random.Random, robot: str, at: datetime) -> dict:
    speed = None if rng.random() < 0.03 else round(rng.uniform(-2, 2), 1)
    inner = rng.choice([rng.randint(0, 4), round(rng.uniform(0, 3), 2)])
    return {
        "id": robot,
        "type": "Robot",
        "TimeInstant": {"type": "DateTime", "value": at.isoformat().replace("+00:00", "Z")},
        "speed": {"type": "Number", "value": speed},
        "count": {"type": "Integer", "value": rng.randint(0, 5)},
        "mode": {"type": "Text", "value": rng.choice(MODES) if rng.random() < 0.2 else None},
        "busy": {"type": "Boolean", "value": rng.random() < 0.5},
        "odom": {"type": "StructuredValue", "value": {"v": inner, "s": rng.choice(MODES[:2])}},
    }


def _times(rng: random.Random, n: int) -> list[datetime]:
    out = []
    while len(out) < n:
        at = T0 + timedelta(microseconds=rng.randrange(HOURS * 3_600_000_000) // 1000 * 1000)
        if not OUTAGE[0] <= at < OUTAGE[1]:
            out.append(at)
    out += rng.sample(out, n // 20)  # the same instant twice: a tie inside the series
    return out


def load(client, seed: int = 38, per_robot: int = 240) -> list[dict]:
    """Store ``per_robot`` (and a few more) states of each robot, out of
    order; the states as sent, in the order sent (which is row-id order)."""
    rng = random.Random(seed)
    states = [_state(rng, robot, at) for robot in ROBOTS for at in _times(rng, per_robot)]
    rng.shuffle(states)
    for i in range(0, len(states), 6):
        body = {"subscriptionId": "longwin", "data": states[i : i + 6]}
        response = client.post("/v2/notify", json=body, headers=HEADERS)
        assert response.status_code == 200, response.text
    return states


def micros(text: str) -> int:
    """An ISO time (``Z`` or an offset) → epoch µs."""
    at = datetime.fromisoformat(text.replace("Z", "+00:00"))
    return (at - datetime(1970, 1, 1, tzinfo=UTC)) // timedelta(microseconds=1)


def samples(states: list[dict], robot: str, attr: str, path: tuple = ()) -> list[tuple[int, object]]:
    """(epoch µs, value) of one robot's attribute (at ``path`` inside it), in
    time order then sending order: the raw samples a bucket is computed from."""
    out = []
    for state in states:
        if state["id"] != robot:
            continue
        value = state[attr]["value"]
        for step in path:
            value = value.get(step) if isinstance(value, dict) else None
        out.append((micros(state["TimeInstant"]["value"]), value))
    out.sort(key=lambda pair: pair[0])  # stable: equal times keep the sending order
    return out
