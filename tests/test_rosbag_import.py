"""``tsdb-service import rosbag``: a robot's bag into history, read back exactly.

Bags are written here with rosbags (both storages), with standard messages
and one custom message defined only in the bag; imported on both backends;
read back through the QuantumLeap API, NGSI-LD, Grafana and the export.
Stamps are honoured, a second import stores nothing, an interrupted import
resumes.
"""

from __future__ import annotations

import io
from datetime import UTC, datetime, timedelta

import orjson
import pyarrow.parquet as pq
import pytest

from tests.support.interrupt import Interrupted, InterruptedTarget
from tests.support.rosbags import CUSTOM_TYPE, write_bag
from tsdb_service.commands.rosbag.importer import import_rosbag
from tsdb_service.commands.rosbag.mapping import load_map
from tsdb_service.core.config import Settings
from tsdb_service.storage import open_store

ROBOT = "urn:ngsi-ld:Robot:R1"
HEADERS = {"Fiware-Service": "robots", "Fiware-ServicePath": "/garden"}
MAP = """\
service: robots
service_path: /garden
entity_type: Robot
topics:
  /fix:
    entity: urn:ngsi-ld:Robot:R1
    attributes:
      location: {path: "", type: geo:json}
      altitude: altitude
  /odom: {entity: urn:ngsi-ld:Robot:R1}
  /battery: {entity: urn:ngsi-ld:Robot:R1, attribute: battery}
  /cmd_vel: {entity: urn:ngsi-ld:Robot:R1}
  /blade: {entity: urn:ngsi-ld:Robot:R1, type: message}
"""
EPOCH = datetime(1970, 1, 1, tzinfo=UTC)


def at(ns: int) -> datetime:
    return EPOCH + timedelta(microseconds=ns // 1000)


def ql_index(moment: datetime) -> str:
    return moment.strftime("%Y-%m-%dT%H:%M:%S.") + f"{moment.microsecond // 1000:03d}+00:00"


def sample_time(w) -> datetime:
    return at(w.stamp_ns if w.stamp_ns is not None else w.receive_ns)


@pytest.fixture(params=["sqlite3", "mcap"])
def bag(request, tmp_path):
    path = tmp_path / f"run-{request.param}"
    return path, write_bag(path, request.param)


@pytest.fixture
def map_file(tmp_path):
    path = tmp_path / "map.yaml"
    path.write_text(MAP)
    return path


def test_a_bag_reads_back_exactly_through_every_api(bag, map_file, store_url, client_factory):
    path, written = bag
    store = open_store(Settings(db=store_url))
    try:
        report = import_rosbag(path, store, spec=load_map(map_file))
    finally:
        store.close()
    assert (report.total, report.messages, report.rejected) == (30, 30, 0)
    assert report.samples == 36  # a fix gives two attributes
    assert report.unstamped == 2  # the battery's zero stamps
    by_topic = {t: [w for w in written if w.topic == t] for t in {w.topic for w in written}}
    with client_factory(store_url) as client:
        for topic, attr in (("/odom", "odom"), ("/battery", "battery"), ("/cmd_vel", "cmd_vel"), ("/blade", "blade")):
            got = client.get(f"/v2/entities/{ROBOT}/attrs/{attr}", headers=HEADERS).json()
            assert got["values"] == [w.message for w in by_topic[topic]], attr
            assert got["index"] == [ql_index(sample_time(w)) for w in by_topic[topic]], attr
        location = client.get(f"/v2/entities/{ROBOT}/attrs/location", headers=HEADERS).json()["values"]
        fixes = [w.message for w in by_topic["/fix"]]
        assert location == [
            {
                "type": "Point",
                "coordinates": [m["longitude"], m["latitude"], *([m["altitude"]] if m["altitude"] else [])],
            }
            for m in fixes
        ]
        assert client.get(f"/v2/entities/{ROBOT}/attrs/altitude", headers=HEADERS).json()["values"] == [
            m["altitude"] for m in fixes
        ]
        _exact_times_and_types(client, written)
        _ngsi_ld(client, by_topic["/battery"])
        _grafana(client, by_topic["/odom"])


def _exact_times_and_types(client, written):
    """The export has every sample's time to the microsecond and its NGSI type."""
    response = client.get("/v2/export", params={"format": "parquet", "attrs": "odom,blade,cmd_vel"}, headers=HEADERS)
    table = pq.read_table(io.BytesIO(response.content)).to_pylist()
    expected = sorted(
        (sample_time(w), {"/odom": "odom", "/blade": "blade", "/cmd_vel": "cmd_vel"}[w.topic], w.message)
        for w in written
        if w.topic in ("/odom", "/blade", "/cmd_vel")
    )
    got = sorted((row["time"], row["attribute"], orjson.loads(row["value_json"])) for row in table)
    assert got == expected
    types = {row["attribute"]: row["ngsi_type"] for row in table}
    assert types == {"odom": "Object", "cmd_vel": "Object", "blade": CUSTOM_TYPE}


def _ngsi_ld(client, battery):
    """NGSI-LD: each message an instance; observedAt the stamp where there was one."""
    answer = client.get(
        f"/ngsi-ld/v1/temporal/entities/{ROBOT}", params={"attrs": "battery"}, headers={"NGSILD-Tenant": "robots"}
    )
    assert answer.status_code == 200, answer.text
    instances = answer.json()["battery"]
    instances = instances if isinstance(instances, list) else [instances]
    assert sorted(orjson.dumps(i["value"]) for i in instances) == sorted(orjson.dumps(w.message) for w in battery)
    assert sorted(datetime.fromisoformat(i["observedAt"]) for i in instances) == [sample_time(w) for w in battery]


def _grafana(client, odom):
    """Grafana (Infinity) reaches into the messages with value paths, at their stamps."""
    answer = client.get(
        "/grafana/infinity/series",
        params={
            "service": "robots",
            "servicepath": "/garden",
            "type": "Robot",
            "attrs": "vx=odom(twist.twist.linear.x)",
            "from": "2024-05-01T09:00:00Z",
            "to": "2024-05-01T11:00:00Z",
        },
    )
    assert answer.status_code == 200, answer.text
    rows = [row for row in answer.json() if row.get("vx") is not None]
    assert [row["vx"] for row in rows] == [w.message["twist"]["twist"]["linear"]["x"] for w in odom]
    assert [datetime.fromisoformat(row["time"]) for row in rows] == [
        sample_time(w).replace(microsecond=sample_time(w).microsecond // 1000 * 1000) for w in odom
    ]


def test_a_second_import_stores_nothing_and_again_imports_once_more(bag, tmp_path, store_url):
    path, _ = bag
    store = open_store(Settings(db=store_url))
    try:
        first = import_rosbag(path, store)
        second = import_rosbag(path, store)
        assert (first.messages, second.messages, second.complete_before) == (30, 0, True)
        assert store.querier().sample_counts() == {"": 30}
        # the same recording in the other storage is the same bag
        other = tmp_path / "converted"
        write_bag(other, "mcap" if path.name.endswith("sqlite3") else "sqlite3")
        assert import_rosbag(other, store).complete_before
        third = import_rosbag(path, store, again=True)
        assert third.messages == 30 and store.querier().sample_counts() == {"": 60}
        assert import_rosbag(path, store).complete_before
    finally:
        store.close()


def test_an_interrupted_import_resumes_without_duplicates_or_gaps(tmp_path, store_url):
    path = tmp_path / "long"
    written = write_bag(path, "mcap", count=40)
    store = open_store(Settings(db=store_url))
    try:
        with pytest.raises(Interrupted):
            import_rosbag(path, InterruptedTarget(store, batches=3), batch_samples=17)
        store.sync()
        partial = store.querier().sample_counts()[""]
        assert 0 < partial < len(written)
        resumed = import_rosbag(path, store, batch_samples=17)
        assert resumed.already == partial and resumed.messages == len(written) - partial
        assert store.querier().sample_counts() == {"": len(written)}
    finally:
        store.close()
    again = open_store(Settings(db=store_url))
    try:
        odom = [w for w in written if w.topic == "/odom"]
        assert _times(again, "urn:ngsi-ld:ROS2Topic:odom") == [sample_time(w) for w in odom]
    finally:
        again.close()


def _times(store, entity_id: str) -> list[datetime]:
    """The series' sample times to the microsecond, in time order."""
    from tsdb_service.core.query import EntityFilter, Scope
    from tsdb_service.read.requests import SeriesSelect

    querier = store.querier()
    [ref] = querier.series(SeriesSelect(Scope(""), EntityFilter(ids=(entity_id,))))
    rows = [row for batch in querier.stored_samples(10_000) for row in batch if row.sid == ref.sid]
    return sorted(row.t.replace(tzinfo=UTC) for row in rows)


def test_without_a_map_each_topic_is_an_entity_and_each_message_the_iot_agent_attribute(tmp_path, client_factory):
    path = tmp_path / "plain"
    written = write_bag(path, "sqlite3", count=2)
    db = str(tmp_path / "t.duckdb")
    store = open_store(Settings(db=db))
    try:
        report = import_rosbag(path, store)
    finally:
        store.close()
    assert {p.entity_id for p in report.plan.topics.values()} == {
        f"urn:ngsi-ld:ROS2Topic:{t}" for t in ("fix", "odom", "battery", "cmd_vel", "blade")
    }
    with client_factory(db) as client:
        entities = client.get("/v2/entities").json()
        assert {e["type"] for e in entities} == {"ROS2Topic"}
        fix = client.get("/v2/entities/urn:ngsi-ld:ROS2Topic:fix/attrs/fix").json()
        assert fix["values"] == [w.message for w in written if w.topic == "/fix"]


def test_a_ros1_bag_is_read_too(tmp_path, client_factory):
    """ROS 1 bags come with rosbags: its time as {"sec", "nanosec"}, stamps honoured."""
    from rosbags.rosbag1 import Writer as Ros1Writer
    from rosbags.typesys import Stores, get_typestore

    store_types = get_typestore(Stores.ROS1_NOETIC)
    t = store_types.types
    path = tmp_path / "old.bag"
    stamps = [(1_714_557_600 + i, 500_000_000 + i) for i in range(3)]
    with Ros1Writer(path) as writer:
        connection = writer.add_connection("/temperature", "sensor_msgs/msg/Temperature", typestore=store_types)
        for i, (sec, nanosec) in enumerate(stamps):
            header = t["std_msgs/msg/Header"](
                seq=i, stamp=t["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec), frame_id="probe"
            )
            message = t["sensor_msgs/msg/Temperature"](header=header, temperature=20.5 + i, variance=0.0)
            raw = store_types.serialize_ros1(message, "sensor_msgs/msg/Temperature")
            writer.write(connection, (sec + 1) * 10**9, raw)
    db = str(tmp_path / "t.duckdb")
    target = open_store(Settings(db=db))
    try:
        report = import_rosbag(
            path, target, spec={"topics": {"/temperature": {"attributes": {"celsius": "temperature"}}}}
        )
    finally:
        target.close()
    assert report.kind == "ROS 1 bag" and report.messages == 3
    with client_factory(db) as client:
        got = client.get("/v2/entities/urn:ngsi-ld:ROS2Topic:temperature/attrs/celsius").json()
    assert got["values"] == [20.5, 21.5, 22.5]
    assert got["index"] == [ql_index(at((sec * 10**9) + nanosec)) for sec, nanosec in stamps]
