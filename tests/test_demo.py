"""The one-command demo: simulators, Orion-faithful notifications, subscriptions.

Offline tests check what the simulators emit and what the files say. The
HTTP tests feed a real server subprocess (each backend) with a bounded,
seeded run of the three simulators through the demo's runner on virtual
time (the notifications of a wall-clock run, as fast as the server
acknowledges them; the wall-clock runs are the ``demo`` command's tests
below), then read everything back through the history API only, as a user
would:

* each use case has its entities, with ROS messages of the right shape;
* the time axis is the simulated one (1 Hz odometry stays 1 s apart);
* states stay within their enumerations;
* the warehouse door is open / opening only while the laser reads < 60 cm;
* the drone's visits per sensor follow the mission priorities;
* the drone's path is noisy, not a straight line.
"""

from __future__ import annotations

import asyncio
import http.server
import io
import json
import math
import random
import statistics
import subprocess
import sys
import threading
import time
from collections import Counter
from datetime import UTC, datetime, timedelta
from itertools import islice, pairwise
from pathlib import Path
from typing import ClassVar

import httpx
import pytest

from tests.support.demo_feed import feed_phases
from tests.support.server import ServerProcess, free_port
from tsdb_service.broker.subscriptions import broker_headers, subscription, write_examples
from tsdb_service.demo.runner import Progress, RunConfig, Stats, VirtualTime, WallTime, _Clock, live_window, run
from tsdb_service.usecases import enums, orion, sites
from tsdb_service.usecases.registry import SIMULATORS

ROOT = Path(__file__).resolve().parents[1]
SEED = 20240611
# (speedup, wall seconds) per simulator: each phase is seeded and bounded in
# simulated time (speedup x seconds), so the data does not depend on speed
# (nor on the clock: the fixture runs them on virtual time).
PHASES = {
    "lawnmower": (120.0, 10.0),  # 20 simulated minutes: a few mowing cycles
    "warehouse": (40.0, 10.0),  # ~7 minutes: a dozen door passes
    "drone": (2000.0, 20.0),  # ~11 hours: some 250 missions
}
MIN_MISSIONS = 200
T0 = datetime(2025, 6, 2, 9, 0, tzinfo=UTC)


def _emissions(name: str, count: int, seed: int = 1) -> list:
    return list(islice(SIMULATORS[name].emissions(T0, random.Random(seed)), count))


# -- offline: what the simulators emit -----------------------------------------


@pytest.mark.parametrize("name", list(SIMULATORS))
def test_a_seed_reproduces_a_run(name):
    first, again, other = _emissions(name, 300), _emissions(name, 300), _emissions(name, 300, seed=2)
    assert [e.entity for e in first] == [e.entity for e in again]
    assert [e.entity for e in first] != [e.entity for e in other]
    assert all(a.at <= b.at for a, b in pairwise(first)), "time must not go back"


def test_headers_are_the_ones_orion_sends():
    headers = orion.notification_headers("Lawnmower", "/bosch", orion.correlator(random.Random(1)))
    assert headers["Content-Type"] == "application/json; charset=utf-8"
    assert headers["Fiware-Service"] == "lawnmower"  # Orion lower-cases the tenant
    assert headers["Fiware-ServicePath"] == "/bosch"
    assert headers["Ngsiv2-AttrsFormat"] == "normalized"
    assert headers["User-Agent"].startswith("orion/4.") and "libcurl/" in headers["User-Agent"]
    uid, _, suffix = headers["Fiware-Correlator"].partition("; ")
    assert len(uid) == 36 and suffix == "cbnotif=1"


@pytest.mark.parametrize("name", list(SIMULATORS))
def test_bodies_are_normalized_ngsiv2_with_time_instant(name):
    body = json.loads(orion.notification_body("5f0c3d7e3b8a4c1e9a572f4d", _emissions(name, 50)[-1].entity))
    assert set(body) == {"subscriptionId", "data"} and len(body["data"]) == 1
    entity = body["data"][0]
    assert entity["TimeInstant"]["type"] == "DateTime"
    stamp = entity["TimeInstant"]["value"]
    assert stamp.endswith("Z") and len(stamp) == len("2025-06-02T09:00:00.000Z")
    for attr, value in entity.items():
        if attr in ("id", "type"):
            continue
        assert set(value) == {"type", "value", "metadata"}, attr
        if attr != "TimeInstant":
            assert value["metadata"]["TimeInstant"]["value"] <= stamp


def test_ros_topics_are_object_attributes_holding_the_message():
    mower = _emissions("lawnmower", 100)[-1].entity
    odom = mower["odom"]
    assert odom["type"] == "Object"
    assert {"header", "child_frame_id", "pose", "twist"} <= set(odom["value"])
    assert set(odom["value"]["twist"]["twist"]["linear"]) == {"x", "y", "z"}
    assert len(odom["value"]["pose"]["covariance"]) == 36
    assert set(mower["obstacleDistance"]["value"]) >= {"range", "min_range", "max_range", "radiation_type"}
    assert mower["navigationState"]["value"]["data"] in enums.LAWNMOWER_NAVIGATION_STATE
    assert mower["location"]["type"] == "geo:json" and mower["location"]["value"]["type"] == "Point"
    lon, lat = mower["location"]["value"]["coordinates"]
    assert sites.distance_m(sites.GARDEN_ORIGIN, (lat, lon)) < 50


def test_enumerations_have_names_for_every_code():
    for use_case, attrs in enums.ENUMERATIONS.items():
        assert use_case in SIMULATORS
        for attr, enumeration in attrs.items():
            assert list(enumeration) == list(range(len(enumeration))), attr
            assert all(isinstance(label, str) and label for label in enumeration.values())
    assert set(enums.DOOR_STATE.values()) == {"closed", "open", "in motion"}
    assert set(enums.DOOR_COMMAND.values()) == {"open", "close", "idle", "stop"}


def test_sites_are_consistent():
    assert len(sites.SENSORS) == 8
    assert sites.MISSION_PRIORITIES == (0.075, 0.075, 0.075, 0.175, 0.1, 0.2, 0.125, 0.175)
    assert math.isclose(sum(sites.MISSION_PRIORITIES), 1.0)
    assert sites.sensors_inside(sites.SENSOR_FIELD) == list(sites.SENSOR_IDS)
    assert not sites.inside(sites.SENSOR_FIELD, sites.DRONE_HOME), "home must be outside the field"
    assert all(300 < sites.distance_m(sites.DRONE_HOME, where) < 3000 for _, where, _ in sites.SENSORS)


# -- offline: the files in notifications/ -------------------------------------------


def test_notification_files_are_generated_from_the_code(tmp_path):
    for path in write_examples(tmp_path):
        committed = ROOT / "notifications" / path.relative_to(tmp_path)
        assert committed.exists(), f"{committed} is missing: run `tsdb-service notifications build`"
        stale = f"{committed} is stale: run `tsdb-service notifications build`"
        assert committed.read_bytes() == path.read_bytes(), stale


@pytest.mark.parametrize("name", list(SIMULATORS))
def test_subscription_selects_the_entities_the_simulator_sends(name):
    import re

    sub = json.loads((ROOT / "notifications" / name / "subscription.json").read_text())
    assert sub["notification"]["attrsFormat"] == "normalized"
    assert sub["notification"]["http"]["url"] == "http://tsdb-service:8668/v2/notify"
    selectors = sub["subject"]["entities"]
    for emission in _emissions(name, 200):
        entity = emission.entity
        assert any(re.search(s["idPattern"], entity["id"]) and s["type"] == entity["type"] for s in selectors), (
            f"{entity['id']} would not be notified"
        )
    headers = json.loads((ROOT / "notifications" / name / "notification.headers.json").read_text())
    body = (ROOT / "notifications" / name / "notification.json").read_bytes()
    assert headers["Fiware-Service"] == SIMULATORS[name].tenancy.service
    assert int(headers["Content-Length"]) == len(json.dumps(json.loads(body), separators=(",", ":")).encode())


# -- subscribe against a stand-in broker on localhost --------------------------------


class _Broker(http.server.BaseHTTPRequestHandler):
    """Records one POST and answers like Orion (201 + Location), or 400 for a
    bad tenant; lists no subscriptions (``subscribe`` looks there first)."""

    received: ClassVar[list] = []  # shared by the handler instances (one per request)

    def do_GET(self):
        self.send_response(200)
        self.send_header("Content-Type", "application/json")
        self.send_header("Content-Length", "2")
        self.end_headers()
        self.wfile.write(b"[]")

    def do_POST(self):
        body = self.rfile.read(int(self.headers["Content-Length"]))
        self.received.append((self.path, dict(self.headers), json.loads(body)))
        if self.headers["Fiware-Service"] == "drone":
            self.send_response(400)
            self.send_header("Content-Type", "application/json")
            self.end_headers()
            self.wfile.write(b'{"error":"BadRequest","description":"no such tenant here"}')
            return
        self.send_response(201)
        self.send_header("Location", "/v2/subscriptions/65f0c3d7e3b8a4c1e9a572f4")
        self.send_header("Content-Length", "0")
        self.end_headers()

    def log_message(self, *args):
        pass


@pytest.fixture
def broker():
    _Broker.received = []
    server = http.server.HTTPServer(("127.0.0.1", 0), _Broker)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    yield f"http://127.0.0.1:{server.server_port}"
    server.shutdown()
    server.server_close()


def test_subscribe_posts_the_subscription_and_reports_the_answer(broker, capsys):
    from tsdb_service.cli.main import main

    notify_url = "http://qa:8668/v2/notify"
    code = main(["subscribe", "--broker", broker, "--use-case", "lawnmower", "--notify-url", notify_url])
    out = capsys.readouterr().out
    assert code == 0
    assert "65f0c3d7e3b8a4c1e9a572f4" in out
    path, headers, body = _Broker.received[0]
    assert path == "/v2/subscriptions"
    assert headers["Fiware-Service"] == "lawnmower" and headers["Fiware-ServicePath"] == "/bosch"
    assert body == subscription(SIMULATORS["lawnmower"], notify_url)


def test_subscribe_reports_a_broker_refusal(broker, capsys):
    from tsdb_service.cli.main import main

    assert main(["subscribe", "--broker", broker, "--use-case", "drone"]) == 1
    out = capsys.readouterr().out
    assert "400" in out and "no such tenant here" in out
    assert _Broker.received[0][1]["Fiware-ServicePath"] == broker_headers(SIMULATORS["drone"])["Fiware-ServicePath"]


# -- through HTTP: a bounded, seeded demo run -----------------------------------------


@pytest.fixture(scope="module")
def demo(store_url_factory):
    """A server on a fresh store (each backend), fed by the three simulators; yields (client, stats)."""
    with ServerProcess(store_url_factory("demo")) as server:
        stats = asyncio.run(feed_phases(server.url, PHASES, seed=SEED, end=datetime.now(UTC)))
        with httpx.Client(base_url=server.url, timeout=30.0) as client:
            yield client, stats


def _get(client: httpx.Client, tenancy: sites.Tenancy, path: str, **params) -> object:
    headers = {"Fiware-Service": tenancy.service, "Fiware-ServicePath": tenancy.service_path}
    response = client.get(path, params=params, headers=headers)
    assert response.status_code == 200, f"GET {path} {params}: {response.status_code} {response.text[:300]}"
    return response.json()


def _series(client, tenancy, entity_id: str, attr: str, **params) -> tuple[list, list]:
    doc = _get(client, tenancy, f"/v2/entities/{entity_id}/attrs/{attr}", **params)
    return doc["index"], doc["values"]


def _wide(client, tenancy, entity_id: str, attrs: list[str], **params) -> list[dict]:
    """Rows of several attributes of one entity, keyed by the names asked for."""
    doc = _get(client, tenancy, f"/v2/entities/{entity_id}", attrs=",".join(attrs), **params)
    columns = {a["attrName"]: a["values"] for a in doc["attributes"]}
    assert set(columns) == set(attrs), f"asked for {attrs}, got {sorted(columns)}"
    return [{"t": t, **{a: columns[a][i] for a in attrs}} for i, t in enumerate(doc["index"])]


def test_every_notification_was_acknowledged(demo):
    _, stats = demo
    for name, row in stats.items():
        assert row.sent > 100, f"{name} sent only {row.sent}"
        assert row.failed == 0 and row.acked == row.sent, f"{name}: {row}"


def test_each_use_case_has_its_entities(demo):
    client, _ = demo
    expected = {
        sites.LAWNMOWER: {sites.LAWNMOWER_ID: "ROS2System"},
        sites.WAREHOUSE: {sites.WAREHOUSE_ID: "ROS2System", sites.WAREHOUSE_ROBOT_ID: "ROS2System"},
        sites.DRONE: {sites.DRONE_ID: "ROS2System"} | dict.fromkeys(sites.SENSOR_IDS, sites.SENSOR_TYPE),
    }
    for tenancy, entities in expected.items():
        listed = _get(client, tenancy, "/v2/entities")
        assert {e["id"]: e["type"] for e in listed} == entities, tenancy


def test_lawnmower_publishes_its_topics_once_a_second(demo):
    client, _ = demo
    doc = _get(client, sites.LAWNMOWER, f"/v2/entities/{sites.LAWNMOWER_ID}", lastN=1)
    latest = {a["attrName"]: a["values"][0] for a in doc["attributes"]}
    assert {
        "odom",
        "location",
        "navigationState",
        "navigationSubState",
        "perimeterLeft",
        "perimeterRight",
        "obstacleDistance",
        "cmd_vel",
    } <= set(latest)
    assert set(latest["cmd_vel"]) == {"linear", "angular"}
    lon, lat = latest["location"]["coordinates"]
    assert sites.distance_m(sites.GARDEN_ORIGIN, (lat, lon)) < 50
    index, speeds = _series(client, sites.LAWNMOWER, sites.LAWNMOWER_ID, "odom(twist.twist.linear.x)")
    speedup, seconds = PHASES["lawnmower"]
    assert len(index) == pytest.approx(speedup * seconds, abs=2)
    steps = {round((_ts(b) - _ts(a)), 3) for a, b in pairwise(index)}
    assert steps == {1.0}, "simulated time, not wall time, is the time index"
    assert statistics.median(v for v in speeds if v > 0.05) == pytest.approx(0.4, abs=0.02), "mowing speed"
    assert max(speeds) < 0.55 and min(speeds) < 0, "remote control at most 0.5 m/s; backing out of the dock"
    _, left = _series(client, sites.LAWNMOWER, sites.LAWNMOWER_ID, "perimeterLeft(data)")
    _, right = _series(client, sites.LAWNMOWER, sites.LAWNMOWER_ID, "perimeterRight(data)")
    assert any(left) and any(right), "the border wire is detected on both sides"


def test_states_are_within_their_enumerations(demo):
    client, _ = demo
    entity_of = {"lawnmower": sites.LAWNMOWER_ID, "warehouse": sites.WAREHOUSE_ID, "drone": sites.DRONE_ID}
    tenancy_of = {"lawnmower": sites.LAWNMOWER, "warehouse": sites.WAREHOUSE, "drone": sites.DRONE}
    for use_case, attrs in enums.ENUMERATIONS.items():
        for attr, enumeration in attrs.items():
            _, values = _series(client, tenancy_of[use_case], entity_of[use_case], f"{attr}(data)")
            seen = Counter(values)
            assert set(seen) <= set(enumeration), f"{use_case} {attr}: {seen}"
            assert len(seen) >= 2, f"{use_case} {attr} never changes: {seen}"
    _, nav = _series(client, sites.LAWNMOWER, sites.LAWNMOWER_ID, "navigationState(data)")
    names = {enums.LAWNMOWER_NAVIGATION_STATE[v] for v in nav}
    assert {"docked", "leaving dock", "mowing", "returning to dock", "docking", "remote control"} <= names


def test_the_door_opens_only_when_the_robot_is_closer_than_60_cm(demo):
    client, _ = demo
    attrs = ["doorState(data)", "doorCommand(data)", "warningLight(data)", "laserDistance(range)"]
    rows = _wide(client, sites.WAREHOUSE, sites.WAREHOUSE_ID, attrs)
    state, command = enums.DOOR_STATE, enums.DOOR_COMMAND
    openings = 0
    for before, row in pairwise(rows):
        near = row["laserDistance(range)"] < sites.DOOR_OPEN_DISTANCE_M
        door, cmd = state[row["doorState(data)"]], command[row["doorCommand(data)"]]
        assert (cmd == "open") == near, f"command {cmd!r} at {row}"
        if door == "open":
            assert near, f"door open with the robot away: {row}"
        if state[before["doorState(data)"]] == "closed" and door != "closed":
            assert near, f"door started opening with the robot away: {row}"
            openings += 1
        light = enums.WARNING_LIGHT_STATE[row["warningLight(data)"]]
        assert (light == "on") == (door != "closed"), f"warning light {light!r} with the door {door!r}"
    assert openings >= 8, f"only {openings} door openings"
    # The robot moves in 10 cm steps from exactly 3 m, so what is left over is the laser's noise.
    laser = [row["laserDistance(range)"] for row in rows if row["laserDistance(range)"] > 0.1]  # not clipped
    residuals = [d - round(d, 1) for d in laser]
    assert statistics.pstdev(residuals) == pytest.approx(0.01, abs=0.003), "the laser has Gaussian noise"
    _, humidity = _series(client, sites.WAREHOUSE, sites.WAREHOUSE_ID, "humidity(data)")
    assert 0.3 < statistics.pstdev(humidity) < 3 and 35 < statistics.mean(humidity) < 55


def test_drone_visits_follow_the_mission_priorities(demo):
    client, _ = demo
    doc = _get(client, sites.DRONE, f"/v2/types/{sites.SENSOR_TYPE}/attrs/temperature", aggrMethod="count")
    visits = {e["id"]: e["values"][0] - 1 for e in doc["entities"]}  # the first reading is the installation
    total = sum(visits.values())
    assert total >= MIN_MISSIONS, f"only {total} missions"
    chi2 = 0.0
    for sensor_id, priority in zip(sites.SENSOR_IDS, sites.MISSION_PRIORITIES, strict=True):
        share = visits.get(sensor_id, 0) / total
        assert abs(share - priority) <= 0.06, f"{sensor_id}: visited {share:.3f}, priority {priority}"
        chi2 += (visits.get(sensor_id, 0) - total * priority) ** 2 / (total * priority)
    assert chi2 < 24.32, f"chi-square {chi2:.1f} with 7 degrees of freedom: p < 0.001"


def test_sensors_hold_their_readings_and_place(demo):
    client, _ = demo
    for sensor_id, (lat, lon), priority in sites.SENSORS:
        doc = _get(client, sites.DRONE, f"/v2/entities/{sensor_id}", lastN=1)
        latest = {a["attrName"]: a["values"][0] for a in doc["attributes"]}
        assert latest["location"] == {"type": "Point", "coordinates": [lon, lat]}
        assert latest["priority"] == priority
        assert -5 < latest["temperature"] < 40 and 0 <= latest["humidity"] <= 100


def test_the_drone_flies_a_noisy_path_and_returns_home(demo):
    client, _ = demo
    attrs = ["location", "missionState(data)", "missionTarget(data)"]
    rows = _wide(client, sites.DRONE, sites.DRONE_ID, attrs, limit=1_000_000)
    speedup, seconds = PHASES["drone"]
    span = _ts(rows[-1]["t"]) - _ts(rows[0]["t"])
    assert span == pytest.approx(speedup * seconds, rel=0.02), "a replay keeps the simulated time axis"
    off_line = []
    for row in rows:
        state = enums.DRONE_MISSION_STATE[row["missionState(data)"]]
        lon, lat = row["location"]["coordinates"]
        if state == "landed at home":
            assert sites.distance_m(sites.DRONE_HOME, (lat, lon)) < 10
        if state == "flying to sensor":
            target = sites.SENSORS[row["missionTarget(data)"] - 1][1]
            off_line.append(_cross_track_m(sites.DRONE_HOME, target, (lat, lon)))
    assert len(off_line) > 1000
    assert max(off_line) < 60, "noisy, yet on its way"
    assert statistics.mean(off_line) > 2, "not an ideal straight line"


def _cross_track_m(a, b, p) -> float:
    """Distance of p from the great circle a→b (small-distance approximation)."""
    course_ab = math.radians(sites.bearing_deg(a, b))
    course_ap = math.radians(sites.bearing_deg(a, p))
    return abs(math.asin(math.sin(sites.distance_m(a, p) / 6_371_000) * math.sin(course_ap - course_ab))) * 6_371_000


def _ts(text: str) -> float:
    return datetime.fromisoformat(text.replace("Z", "+00:00")).timestamp()


# -- the command itself ----------------------------------------------------------------


def test_demo_command_serves_feeds_and_prints_where_to_look(tmp_path):
    port = free_port()
    db = tmp_path / "data" / "tsdb.duckdb"
    command = [
        sys.executable,
        "-m",
        "tsdb_service",
        "demo",
        "--db",
        str(db),
        "--port",
        str(port),
        "--duration",
        "3",
        "--speedup",
        "30",
        "--seed",
        "1",
    ]
    done = subprocess.run(command, capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert done.returncode == 0, done.stdout + done.stderr
    out = done.stdout
    url = f"http://127.0.0.1:{port}"
    for where in (f"{url}/docs", f"{url}/ui/#/dashboards", f"curl -s '{url}/v2/", "-H 'Fiware-Service: "):
        assert where in out, out
    # It says it listens on this machine only, and how another one reaches it.
    assert f"listening    127.0.0.1:{port} only" in out and f"ssh -L {port}:127.0.0.1:{port}" in out, out
    assert "--host 0.0.0.0" in out and "no authentication" in out, out
    assert ", 0 failed (seed 1)" in out, out
    for name in SIMULATORS:
        assert f"  {name}" in out, out
    assert db.exists()
    # the lawnmower's recorded run (a ROS 2 bag) was imported at start, and says where to see it
    assert "Recorded run: the lawnmower's ROS 2 bag" in out and "format=mcap" in out, out
    assert _recorded_odom(db) == 360


def _recorded_odom(db: Path) -> int:
    """Odometry samples of the demo's lawnmower in the recorded run's time range."""
    from tsdb_service.core.config import Settings
    from tsdb_service.core.query import EntityFilter, Scope, TimeRange
    from tsdb_service.demo.bag import BAG_SECONDS, BAG_START
    from tsdb_service.read.requests import SamplesIn, SeriesSelect
    from tsdb_service.storage import open_store

    store = open_store(Settings(db=str(db)))
    try:
        querier = store.querier()
        refs = querier.series(
            SeriesSelect(Scope(sites.LAWNMOWER.service), EntityFilter(ids=(sites.LAWNMOWER_ID,)), ("odom",))
        )
        span = TimeRange(BAG_START, BAG_START + timedelta(seconds=BAG_SECONDS))
        return querier.count(SamplesIn([r.sid for r in refs], span))
    finally:
        store.close()


# -- one instant, one state ----------------------------------------------------------------


@pytest.mark.parametrize("name", list(SIMULATORS))
def test_an_entity_has_one_state_per_instant(name):
    """Orion timestamps have milliseconds: two updates of one entity in the same
    millisecond are two states of one instant (the drone reported its arrival
    twice, with different positions and altitudes)."""
    seen = Counter((e.entity["id"], orion.iso(e.at)) for e in _emissions(name, 20_000))
    twice = [key for key, n in seen.items() if n > 1]
    assert not twice, f"{len(twice)} instants with two states, e.g. {twice[:2]}"


# -- live runs: the time window ---------------------------------------------------------------

NOW = datetime(2025, 6, 2, 12, 0, tzinfo=UTC)


def test_a_bounded_run_at_speed_1_is_live():
    start, speedup = live_window(1.0, 60, NOW)
    assert (start, speedup) == (NOW, 1.0), "simulated time is the clock's"


def test_a_fast_bounded_run_catches_up_with_the_clock():
    start, speedup = live_window(10.0, 60, NOW)
    assert speedup == 10.0
    assert start == NOW - timedelta(seconds=540), "600 simulated seconds ending when the run ends"
    assert start + timedelta(seconds=60 * speedup) == NOW + timedelta(seconds=60)


def test_a_slow_or_open_ended_run_never_writes_the_future():
    assert live_window(0.5, 60, NOW) == (NOW, 0.5)
    assert live_window(20.0, None, NOW) == (NOW, 20.0)


def test_a_run_starts_after_an_earlier_run_and_still_ends_on_time():
    earlier_end = NOW - timedelta(seconds=30)
    start, speedup = live_window(10.0, 60, NOW, previous_end=earlier_end)
    assert start > earlier_end
    end = start + timedelta(seconds=60 * speedup)
    assert abs(end - (NOW + timedelta(seconds=60))) <= timedelta(milliseconds=2), "still ends on time"
    assert live_window(10.0, 60, NOW, previous_end=NOW - timedelta(hours=2)) == live_window(10.0, 60, NOW)
    assert live_window(1.0, 60, NOW, previous_end=NOW + timedelta(seconds=5))[0] > NOW + timedelta(seconds=5)
    with pytest.raises(ValueError, match="beyond this run's end"):
        live_window(10.0, 60, NOW, previous_end=NOW + timedelta(hours=1))


# -- live runs: falling behind -----------------------------------------------------------------


class _SlowService(http.server.BaseHTTPRequestHandler):
    """Acknowledges every notification, 20 ms late: a service the simulators outrun."""

    def do_POST(self):
        self.rfile.read(int(self.headers["Content-Length"]))
        time.sleep(0.02)
        self.send_response(200)
        self.send_header("Content-Length", "0")
        self.end_headers()

    def log_message(self, *args):
        pass


def test_the_progress_display_says_how_far_behind_and_when_it_ends():
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), _SlowService)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    out = io.StringIO()
    try:
        config = RunConfig(f"http://127.0.0.1:{server.server_port}", speedup=100.0, duration=0.5, seed=1, concurrency=1)
        stats = asyncio.run(run([SIMULATORS["warehouse"]], config, progress=Progress(out, interval=0.25)))
    finally:
        server.shutdown()
        server.server_close()
    assert stats["warehouse"].failed == 0 and stats["warehouse"].sent > 100
    text = out.getvalue()
    assert "BEHIND by" in text and "ends in ~" in text and "after --duration 0.5" in text, text
    assert " s over, the simulators could not keep up with x100" in text, text


def test_the_expected_end_follows_the_pace_so_far():
    start = NOW
    clock = _Clock(start, 200.0, duration=60.0, wall_start=time.monotonic() - 100.0)
    row = Stats("drone", sim_time=start + timedelta(seconds=40 * 200.0), lag=60.0)
    assert clock.expected_end([row]) == pytest.approx(150.0, abs=0.5), "40 planned s in 100 s: 20 more take 50"
    line = Progress.summary({"drone": row}, clock)
    assert "BEHIND by 60.0 s" in line and "ends in ~50 s" in line and "90 s after --duration 60" in line


# -- virtual time: the same notifications, without the waiting ------------------------------------


class _Recorder(http.server.BaseHTTPRequestHandler):
    """Acknowledges every notification and keeps its body, in arrival order."""

    protocol_version = "HTTP/1.1"  # keep-alive, as the service
    bodies: ClassVar[list] = []

    def do_POST(self):
        self.bodies.append(json.loads(self.rfile.read(int(self.headers["Content-Length"]))))
        self.send_response(200)
        self.send_header("Content-Length", "0")
        self.end_headers()

    def log_message(self, *args):
        pass


def _recorded_run(names: list[str], timer, concurrency: int = 1) -> tuple[list[dict], dict[str, Stats], float]:
    """(bodies in arrival order, stats, wall seconds) of a bounded run against a stand-in."""
    _Recorder.bodies = []
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), _Recorder)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        config = RunConfig(
            f"http://127.0.0.1:{server.server_port}",
            speedup=200.0,
            duration=0.3,
            seed=4,
            concurrency=concurrency,
            start=T0,
        )
        began = time.monotonic()
        stats = asyncio.run(run([SIMULATORS[name] for name in names], config, timer=timer))
        return list(_Recorder.bodies), stats, time.monotonic() - began
    finally:
        server.shutdown()
        server.server_close()


def _stamp(body: dict) -> str:
    return body["data"][0]["TimeInstant"]["value"]


def test_virtual_time_sends_what_the_wall_clock_sends():
    wall, wall_stats, _ = _recorded_run(["warehouse"], WallTime())
    virtual, virtual_stats, _ = _recorded_run(["warehouse"], VirtualTime())
    assert len(wall) > 100 and wall_stats["warehouse"].acked == len(wall)
    assert virtual == wall, "same bodies, same order"
    assert virtual_stats["warehouse"].sent == wall_stats["warehouse"].sent
    assert virtual_stats["warehouse"].lag == 0.0 and virtual_stats["warehouse"].done


def test_virtual_time_interleaves_simulators_in_time_order():
    bodies, stats, _ = _recorded_run(["lawnmower", "warehouse", "drone"], VirtualTime())
    stamps = [_stamp(body) for body in bodies]
    assert stamps == sorted(stamps), "one clock for every simulator: emissions leave in time order"
    assert {body["data"][0]["id"] for body in bodies} >= {sites.LAWNMOWER_ID, sites.WAREHOUSE_ID, sites.DRONE_ID}
    assert stamps[-1] <= orion.iso(T0 + timedelta(seconds=60.0)), "bounded by the simulated span"
    assert all(row.done and row.failed == 0 and row.acked == row.sent for row in stats.values())
    assert sum(row.sent for row in stats.values()) == len(bodies)


# -- live runs: the command -------------------------------------------------------------------------


def _demo(db: Path, *args: str) -> tuple[subprocess.CompletedProcess, float, float]:
    command = [
        sys.executable,
        "-m",
        "tsdb_service",
        "demo",
        "--db",
        str(db),
        "--port",
        str(free_port()),
        "--use-case",
        "warehouse",
        "--seed",
        "3",
        *args,
    ]
    began = time.time()
    done = subprocess.run(command, capture_output=True, text=True, timeout=120, cwd=db.parent)
    assert done.returncode == 0, done.stdout + done.stderr
    return done, began, time.time()


def _stored_span(db: Path) -> tuple[float, float]:
    from tsdb_service.core.config import Settings
    from tsdb_service.storage import open_store

    store = open_store(Settings(db=str(db)))
    try:
        first, last = store.querier()._fetch("SELECT min(t), max(t) FROM samples_all", [])[0]
    finally:
        store.close()
    return first.replace(tzinfo=UTC).timestamp(), last.replace(tzinfo=UTC).timestamp()


def _planned_window(out: str) -> tuple[float, float]:
    """The banner's "simulated time START to END: ..." as epoch seconds."""
    words = next(line for line in out.splitlines() if "simulated time" in line).split()
    return _ts(words[2]), _ts(words[4].rstrip(":"))


def test_demo_runs_are_live_and_do_not_overlap(tmp_path):
    db = tmp_path / "tsdb.duckdb"
    done, began, ended = _demo(db, "--duration", "3")
    start, end = _planned_window(done.stdout)
    first, last = _stored_span(db)
    assert began < start and end - start == pytest.approx(3.0, abs=0.01), done.stdout
    assert end <= ended, "no data from the future"
    assert last == pytest.approx(end, abs=0.6), "the data ends when the run ends (ticks are 0.5 s)"

    again, _, ended_again = _demo(db, "--duration", "3", "--speedup", "30")
    start2, end2 = _planned_window(again.stdout)
    first2, last2 = _stored_span(db)
    assert first2 == first
    assert start2 > last, "a second run starts after the first one's data"
    assert "replays at x" in again.stdout and "to still end on time" in again.stdout, again.stdout
    assert last2 == pytest.approx(end2, abs=0.6) and end2 <= ended_again
