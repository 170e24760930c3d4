"""``tsdb-service replay``: stored history sent again, in order, paced, marked, never into its own tenant.

Into another tsdb-service (a real one, a separate process) and through a
private Mosquitto (real), checking order, pacing within 10% at ``--speed
10``, the ``tsdbReplay`` marker, and that the source tenant receives
nothing; the Orion and Orion-LD targets against their documented request
shapes (a stand-in that records what it is sent).
"""

from __future__ import annotations

import subprocess
import threading
import time
from datetime import UTC, datetime, timedelta

import httpx
import orjson
import paho.mqtt.client as paho
import pytest

from tests.support.cli import assert_usage_error
from tests.support.mosquitto import unique_client_id
from tests.support.server import ServerProcess
from tests.support.standins import StandInOrion, served
from tsdb_service.core.config import Settings

START = datetime(2024, 5, 1, 10, 0, tzinfo=UTC)
INSTANTS = 11  # one a second: 10 s of history, 1 s at --speed 10
SOURCE = {"Fiware-Service": "robots", "Fiware-ServicePath": "/garden"}


def _entities(i: int) -> list[dict]:
    at = (START + timedelta(seconds=i)).isoformat().replace("+00:00", "Z")
    robot = {
        "id": "urn:ngsi-ld:Robot:R1",
        "type": "Robot",
        "TimeInstant": {"type": "DateTime", "value": at},
        "speed": {"type": "Number", "value": 0.25 * i},
        "odom": {"type": "Object", "value": {"header": {"stamp": {"sec": 1714557600 + i, "nanosec": 0}}, "x": i}},
        "location": {"type": "geo:json", "value": {"type": "Point", "coordinates": [11.5 + i / 1000, 48.1]}},
    }
    dock = {"id": "urn:ngsi-ld:Dock:D1", "type": "Dock", "TimeInstant": {"type": "DateTime", "value": at}}
    dock["occupied"] = {"type": "Boolean", "value": i % 2 == 0}
    return [robot, dock] if i % 5 == 0 else [robot]


@pytest.fixture(scope="module")
def source(tmp_path_factory):
    """A DuckDB file holding the robots' history (no service holds it)."""
    from fastapi.testclient import TestClient

    from tsdb_service.app import create_app

    db = str(tmp_path_factory.mktemp("replay") / "source.duckdb")
    with TestClient(create_app(Settings(db=db))) as client:  # closing it applies and checkpoints everything
        for i in range(INSTANTS):
            body = {"subscriptionId": "s", "data": _entities(i)}
            assert client.post("/v2/notify", json=body, headers=SOURCE).status_code == 200
    return db


@pytest.fixture
def replay(capsys):
    from tsdb_service.cli.main import main

    def run(*args: str) -> subprocess.CompletedProcess:
        code = main(["replay", "--quiet", *args])
        out, err = capsys.readouterr()
        return subprocess.CompletedProcess([], code, out, err)

    return run


def _expected_updates() -> list[tuple[datetime, str]]:
    return [(START + timedelta(seconds=i), e["id"]) for i in range(INSTANTS) for e in _entities(i)]


# --- into another tsdb-service ---------------------------------------------------------


def test_into_another_service_in_order_marked_paced_and_not_into_the_source_tenant(source, replay, tmp_path):
    with ServerProcess(tmp_path / "target.duckdb") as target:
        done = replay(
            "--db", source, "--service", "robots", "--to-notify", target.url, "--to-service", "staging",
            "--speed", "10", "--retime",
        )  # fmt: skip
        assert done.returncode == 0, done.stderr
        assert f"replayed {len(_expected_updates())} updates" in done.stdout
        staging = {"Fiware-Service": "staging", "Fiware-ServicePath": "/garden"}
        speed = httpx.get(f"{target.url}/v2/entities/urn:ngsi-ld:Robot:R1/attrs/speed", headers=staging).json()
        assert speed["values"] == [0.25 * i for i in range(INSTANTS)]
        marks = httpx.get(f"{target.url}/v2/entities/urn:ngsi-ld:Robot:R1/attrs/tsdbReplay", headers=staging).json()
        originals = [datetime.fromisoformat(m["originalTime"]) for m in marks["values"]]
        assert originals == [START + timedelta(seconds=i) for i in range(INSTANTS)]
        assert all(m["source"].startswith("robots on ") and len(m["replay"]) == 12 for m in marks["values"])
        # --retime: stored at the time each was sent, which shows the pacing: 0.1 s apart within 10%
        sent = [datetime.fromisoformat(t) for t in speed["index"]]
        _assert_paced([(t - sent[0]).total_seconds() for t in sent])
        odom = httpx.get(f"{target.url}/v2/entities/urn:ngsi-ld:Robot:R1/attrs/odom", headers=staging).json()
        assert [v["x"] for v in odom["values"]] == list(range(INSTANTS))
        # nothing went to the tenant it reads from
        assert httpx.get(f"{target.url}/v2/entities", headers={"Fiware-Service": "robots"}).json() == []
        hint = httpx.get(f"{target.url}/v2/entities").headers["x-tsdb-hint"]
        assert "staging" in hint and "robots" not in hint


def _assert_paced(offsets: list[float]) -> None:
    """One instant a second of history at --speed 10: update i is due 0.1 s x i after the start.
    Measured against the schedule that fits best (the median lag, so a late first update does
    not shift the rest), every update is within 10% of the whole second (0.1 s) of its due time
    but one (a single stall of a process on a busy shared machine: the replay never skips ahead,
    so it does not carry over), and half are within 30 ms (a wrong speed or a drift is not)."""
    errors = sorted(offset - i / 10 for i, offset in enumerate(offsets))
    lag = errors[len(errors) // 2]
    deviations = sorted(abs(e - lag) for e in errors)
    assert deviations[-2] <= 0.1, offsets
    assert deviations[len(deviations) // 2] <= 0.03, offsets


def test_original_times_are_kept_without_retime(source, replay, tmp_path):
    with ServerProcess(tmp_path / "target.duckdb") as target:
        done = replay("--db", source, "--service", "robots", "--to-notify", target.url, "--to-service", "staging",
                      "--no-pacing", "--type", "Dock")  # fmt: skip
        assert done.returncode == 0, done.stderr
        got = httpx.get(
            f"{target.url}/v2/entities/urn:ngsi-ld:Dock:D1/attrs/occupied", headers={"Fiware-Service": "staging"}
        ).json()
        assert got["index"] == [f"2024-05-01T10:00:{s:02d}.000+00:00" for s in (0, 5, 10)]
        assert got["values"] == [True, False, True]


def test_the_source_tenant_is_refused_unless_forced(source, replay):
    with served(StandInOrion()) as orion:
        for args in (("--to-orion", orion.url), ("--to-orion", orion.url, "--to-service", "Robots")):
            done = replay("--db", source, "--service", "robots", *args)
            assert_usage_error(done, "tenant it reads from (robots)", "--force")
        assert orion.updates == []
        assert (
            replay("--db", source, "--service", "robots", "--to-orion", orion.url, "--force", "--no-pacing").returncode
            == 0
        )
        assert {headers["fiware-service"] for _, headers, _ in orion.updates} == {"robots"}


@pytest.mark.parametrize(
    "args, needle",
    [
        (("--to-orion", "ftp://orion"), "http:// or https://"),
        (("--to-mqtt", "http://broker"), "mqtt://host:1883"),
        ((), "give one target"),
        (("--to-orion", "http://a", "--to-notify", "http://b"), "give one target"),
        (("--to-orion", "http://a", "--to-service", "no good"), "--to-service"),
        (("--to-orion", "http://a", "--mqtt-topic", "x"), "go with --to-mqtt"),
        (("--to-orion", "http://a", "--from-date", "yesterday"), "fromDate"),
    ],
)
def test_bad_arguments_are_one_line(source, replay, args, needle):
    assert_usage_error(replay("--db", source, "--service", "robots", *args), needle)


def test_a_store_that_is_not_there_is_one_line_and_not_created(replay, tmp_path):
    missing = tmp_path / "missing.duckdb"
    assert_usage_error(replay("--db", str(missing), "--to-orion", "http://a", "--to-service", "x"), "no database at")
    assert not missing.exists()
    assert_usage_error(replay("--url", "ftp://a", "--to-orion", "http://a", "--to-service", "x"), "http://")


# --- Orion and Orion-LD: the documented request shapes ----------------------------------------


def test_orion_gets_op_update_append_in_normalized_form(source, replay):
    with served(StandInOrion()) as orion:
        done = replay("--db", source, "--service", "robots", "--to-orion", orion.url, "--to-service", "staging",
                      "--to-service-path", "/replayed", "--no-pacing")  # fmt: skip
        assert done.returncode == 0, done.stderr
    assert len(orion.updates) == INSTANTS  # one request per instant
    for path, headers, body in orion.updates:
        assert path == "/v2/op/update"
        assert headers["fiware-service"] == "staging" and headers["fiware-servicepath"] == "/replayed"
        assert headers["content-type"] == "application/json"
        assert body["actionType"] == "append" and body["entities"]
        for entity in body["entities"]:
            for name, attr in entity.items():
                if name not in ("id", "type"):
                    assert set(attr) == {"type", "value"}, (name, attr)
            assert entity["tsdbReplay"]["type"] == "StructuredValue"
            assert entity["TimeInstant"]["value"] == entity["tsdbReplay"]["value"]["originalTime"]
    sent = [
        (datetime.fromisoformat(e["TimeInstant"]["value"]), e["id"]) for _, _, b in orion.updates for e in b["entities"]
    ]
    assert sent == _expected_updates()
    first = orion.updates[0][2]["entities"][0]
    assert first["location"] == {"type": "geo:json", "value": {"type": "Point", "coordinates": [11.5, 48.1]}}
    assert first["odom"]["type"] == "Object" and first["speed"] == {"type": "Number", "value": 0.0}


def test_orion_ld_gets_a_batch_upsert_of_properties(source, replay):
    with served(StandInOrion()) as orion:
        done = replay("--db", source, "--service", "robots", "--to-orion-ld", orion.url, "--to-service", "staging",
                      "--no-pacing")  # fmt: skip
        assert done.returncode == 0, done.stderr
    assert len(orion.updates) == INSTANTS
    for path, headers, body in orion.updates:
        assert path == "/ngsi-ld/v1/entityOperations/upsert?options=update"
        assert headers["ngsild-tenant"] == "staging" and headers["content-type"] == "application/json"
        assert "link" not in headers and isinstance(body, list)
        for entity in body:
            observed = {a["observedAt"] for k, a in entity.items() if k not in ("id", "type")}
            assert len(observed) == 1  # every attribute observed at the sample's time
            assert entity["tsdbReplay"]["type"] == "Property"
            assert entity["tsdbReplay"]["value"]["originalTime"] == observed.pop()
    robot = orion.updates[0][2][0]
    assert robot["location"]["type"] == "GeoProperty" and robot["location"]["value"]["type"] == "Point"
    assert robot["speed"]["type"] == "Property" and "TimeInstant" not in robot


# --- MQTT: what Orion and Orion-LD publish, read back by our own MQTT ingest ------------------


class _Subscriber:
    def __init__(self, url: str):
        host, port = url.removeprefix("mqtt://").rsplit(":", 1)
        self.got: list[tuple[float, str, bytes]] = []
        self.ready = threading.Event()
        self.client = paho.Client(paho.CallbackAPIVersion.VERSION2, client_id=unique_client_id("replay-sub"))
        self.client.on_connect = lambda c, u, f, rc, p: c.subscribe("tsdb/#", qos=1)
        self.client.on_subscribe = lambda *_: self.ready.set()
        self.client.on_message = lambda c, u, m: self.got.append((time.monotonic(), m.topic, m.payload))
        self.client.connect(host, int(port))
        self.client.loop_start()
        assert self.ready.wait(10)

    def wait(self, count: int) -> None:
        deadline = time.monotonic() + 20
        while len(self.got) < count and time.monotonic() < deadline:
            time.sleep(0.02)

    def close(self) -> None:
        self.client.loop_stop()
        self.client.disconnect()


@pytest.mark.parametrize("shape", ["orion", "orion-ld"])
def test_into_mqtt_as_the_brokers_publish_paced_and_read_by_our_ingest(source, replay, mosquitto, shape):
    from tsdb_service.ingest.mqtt.config import MqttConfig
    from tsdb_service.ingest.mqtt.messages import Message, parse_message

    subscriber = _Subscriber(mosquitto.url)
    try:
        done = replay("--db", source, "--service", "robots", "--to-mqtt", mosquitto.url, "--to-service", "staging",
                      "--mqtt-shape", shape, "--speed", "10")  # fmt: skip
        assert done.returncode == 0, done.stderr
        subscriber.wait(INSTANTS)
    finally:
        subscriber.close()
    assert len(subscriber.got) == INSTANTS
    assert {topic for _, topic, _ in subscriber.got} == {"tsdb/staging/garden"}
    _assert_paced([at - subscriber.got[0][0] for at, _, _ in subscriber.got])
    config = MqttConfig.from_settings(Settings(mqtt_url=mosquitto.url))
    parsed = []
    for _, topic, payload in subscriber.got:
        message = Message(topic, payload, 1, False, 1, b"", (), datetime.now(UTC))
        parsed += parse_message(message, config)
    assert {(e.tenant, e.service_path) for e in parsed} == {("staging", "/garden")}
    assert [(e.time_index, e.entity_id) for e in parsed] == _expected_updates()
    assert all("tsdbReplay" in {a.name for a in e.attrs} for e in parsed)
    if shape == "orion-ld":
        assert all(orjson.loads(p)["metadata"]["NGSILD-Tenant"] == "staging" for _, _, p in subscriber.got)


def test_a_store_a_service_holds_is_read_through_that_service(source, replay, tmp_path):
    import shutil

    held = tmp_path / "held.duckdb"
    shutil.copy(source, held)
    with ServerProcess(held) as service, served(StandInOrion()) as orion:
        done = replay("--db", str(held), "--service", "robots", "--to-orion", orion.url, "--to-service", "staging",
                      "--no-pacing")  # fmt: skip
        assert done.returncode == 0, done.stderr
        assert f"is held by the service at {service.url}" in done.stderr
        through_holder = list(orion.updates)
        orion.updates.clear()
        done = replay("--url", service.url, "--service", "robots", "--to-orion", orion.url, "--to-service", "staging",
                      "--no-pacing")  # fmt: skip
        assert done.returncode == 0, done.stderr
    for updates in (through_holder, orion.updates):
        entities = [e for _, _, body in updates for e in body["entities"]]
        assert [(datetime.fromisoformat(e["TimeInstant"]["value"]), e["id"]) for e in entities] == _expected_updates()
        speeds = [e["speed"]["value"] for e in entities if "speed" in e]
        assert speeds == [0.25 * i for i in range(INSTANTS)]
        assert entities[0]["odom"]["value"] == {"header": {"stamp": {"sec": 1714557600, "nanosec": 0}}, "x": 0}
