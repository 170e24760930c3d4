"""Bad input to ``import rosbag``: one clear error line, and nothing half-imported.

A damaged or truncated bag, a type the bag does not define, a map naming
fields the messages do not have: each is found before anything is written
(the store is not even created), as one ``error:`` line and exit status 2.
One message whose bytes do not fit its type is kept in the rejected store
and the rest imported.
"""

from __future__ import annotations

import subprocess

import apsw
import pytest
from rosbags.rosbag2 import Writer
from rosbags.rosbag2.enums import StoragePlugin

from tests.support.cli import assert_usage_error
from tests.support.rosbags import CUSTOM_TYPE, typestore, write_bag
from tsdb_service.commands.rosbag.importer import UNREADABLE, import_rosbag
from tsdb_service.core.config import Settings
from tsdb_service.storage import open_store


@pytest.fixture
def import_bag(capsys):
    """``tsdb-service import rosbag BAG --db DB ...`` in this process (as ``main`` runs it)."""
    from tsdb_service.cli.main import main

    def run(bag, db, *more) -> subprocess.CompletedProcess:
        code = main(["import", "rosbag", str(bag), "--db", str(db), "--quiet", *more])
        out, err = capsys.readouterr()
        return subprocess.CompletedProcess([], code, out, err)

    return run


def _refused(done, db, *needles):
    assert_usage_error(done, *needles)
    assert not db.exists(), "the store must not even be created"


def test_a_truncated_mcap_file_is_one_line(tmp_path, import_bag):
    bag = tmp_path / "run"
    write_bag(bag, "mcap")
    whole = (bag / "run.mcap").read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(whole[: len(whole) * 2 // 3])
    _refused(import_bag(cut, tmp_path / "t.duckdb"), tmp_path / "t.duckdb", str(cut))


def test_a_truncated_sqlite_bag_is_one_line(tmp_path, import_bag):
    bag = tmp_path / "run"
    write_bag(bag, "sqlite3", count=200)
    storage = bag / "run.db3"
    storage.write_bytes(storage.read_bytes()[: storage.stat().st_size // 2])
    _refused(import_bag(bag, tmp_path / "t.duckdb"), tmp_path / "t.duckdb", str(bag))


def test_a_damaged_sqlite_bag_is_one_line(tmp_path, import_bag):
    bag = tmp_path / "run"
    write_bag(bag, "sqlite3", count=200)
    storage = bag / "run.db3"
    data = bytearray(storage.read_bytes())
    page = 4096
    for start in range(page, len(data) - page, 3 * page):
        data[start : start + 64] = b"\xa5" * 64  # the b-tree pages' headers
    storage.write_bytes(bytes(data))
    _refused(import_bag(bag, tmp_path / "t.duckdb"), tmp_path / "t.duckdb", "damaged")


def test_a_path_that_is_no_bag_is_one_line(tmp_path, import_bag):
    (tmp_path / "empty").mkdir()
    _refused(import_bag(tmp_path / "empty", tmp_path / "t.duckdb"), tmp_path / "t.duckdb", "metadata.yaml")
    _refused(import_bag(tmp_path / "nothing", tmp_path / "t.duckdb"), tmp_path / "t.duckdb", "no bag at")


def test_a_bag_without_messages_imports_nothing_and_creates_no_store(tmp_path, import_bag):
    write_bag(tmp_path / "empty", count=0)
    done = import_bag(tmp_path / "empty", tmp_path / "t.duckdb")
    assert done.returncode == 0 and "nothing to import" in done.stdout, done.stdout + done.stderr
    assert not (tmp_path / "t.duckdb").exists()


def test_an_unknown_message_type_without_a_definition(tmp_path, import_bag):
    bag = tmp_path / "run"
    write_bag(bag, "sqlite3", count=2)
    with apsw.Connection(str(bag / "run.db3")) as db3:  # as rosbag2 before Iron: no definitions stored
        db3.execute("DELETE FROM message_definitions")
    db = tmp_path / "t.duckdb"
    _refused(import_bag(bag, db), db, "/blade", CUSTOM_TYPE, "no definition")
    # the standard types come from rosbags' own definitions: skipping the custom topic imports the rest
    (tmp_path / "map.toml").write_text('[topics]\n"/blade" = "skip"\n')
    done = import_bag(bag, db, "--map", str(tmp_path / "map.toml"))
    assert done.returncode == 0, done.stderr
    assert "import verified: 8 messages" in done.stdout and "skipped: /blade" in done.stdout


def test_an_mcap_channel_that_is_not_json_is_refused_unless_skipped(tmp_path, import_bag):
    from mcap.writer import Writer as McapWriter

    recorded = tmp_path / "foxglove.mcap"  # as Foxglove records: JSON beside another encoding
    with recorded.open("wb") as stream:
        writer = McapWriter(stream)
        writer.start()
        schema = writer.register_schema(name="Pose", encoding="jsonschema", data=b'{"type": "object"}')
        pose = writer.register_channel(topic="/pose", message_encoding="json", schema_id=schema)
        other = writer.register_channel(topic="/camera", message_encoding="cbor", schema_id=0)
        for i in range(3):
            writer.add_message(channel_id=pose, log_time=10**18 + i, publish_time=0, data=b'{"x": %d}' % i)
            writer.add_message(channel_id=other, log_time=10**18 + i, publish_time=0, data=b"\xa0")
        writer.finish()
    db = tmp_path / "t.duckdb"
    _refused(import_bag(recorded, db), db, "/camera", "cbor-encoded", "skip")
    (tmp_path / "map.yaml").write_text("topics:\n  /camera: skip\n")
    done = import_bag(recorded, db, "--map", str(tmp_path / "map.yaml"))
    assert done.returncode == 0, done.stderr
    assert "import verified: 3 messages" in done.stdout and "skipped: /camera" in done.stdout


@pytest.mark.parametrize(
    "topic_map, needles",
    [
        ("{attributes: {speed: twist.twist.linear.q}}", ["speed", "twist.twist.linear.q", "no field 'q'", "x, y, z"]),
        ("{attributes: {c: 'pose.covariance[36]'}}", ["has 36 elements"]),
        ("{attributes: {c: 'pose[0]'}}", ["is not an array"]),
        ("{attributes: {'bad name': pose}}", ["attribute name 'bad name'"]),
        ("{attribute: odom, attributes: {x: pose}}", ["not both"]),
        ("{entity: 'a,b'}", ["entity 'a,b'"]),
        ("{service: 'Not-A-Tenant'}", ["service"]),
        ("{time: header.stamp.when}", ["no field 'when'"]),
        ("{colour: red}", ["unknown key 'colour'"]),
        ("{attributes: {where: {path: '', type: 'geo:json'}}}", ["geo:json needs a message with latitude"]),
    ],
)
def test_a_map_naming_what_the_messages_do_not_have(tmp_path, import_bag, topic_map, needles):
    bag = tmp_path / "run"
    write_bag(bag, "mcap", count=1)
    (tmp_path / "map.yaml").write_text(f"topics:\n  /odom: {topic_map}\n")
    db = tmp_path / "t.duckdb"
    _refused(import_bag(bag, db, "--map", str(tmp_path / "map.yaml")), db, "/odom", *needles)


def test_a_map_that_is_no_map(tmp_path, import_bag):
    bag = tmp_path / "run"
    write_bag(bag, "mcap", count=1)
    db = tmp_path / "t.duckdb"
    (tmp_path / "map.yaml").write_text("topics: [1, 2\n")
    _refused(import_bag(bag, db, "--map", str(tmp_path / "map.yaml")), db, "not valid YAML")
    (tmp_path / "map.yaml").write_text("topics:\n  /lidar: skip\n")
    _refused(import_bag(bag, db, "--map", str(tmp_path / "map.yaml")), db, "/lidar is not in the bag")
    _refused(import_bag(bag, db, "--map", str(tmp_path / "none.yaml")), db, "cannot read the map")


def test_one_undecodable_message_is_kept_in_the_rejected_store_and_the_rest_imported(tmp_path, store_url):
    bag = tmp_path / "run"
    store_types = typestore()
    with Writer(bag, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        connection = writer.add_connection("/cmd_vel", "geometry_msgs/msg/Twist", typestore=store_types)
        twist = store_types.types["geometry_msgs/msg/Twist"]
        vector = store_types.types["geometry_msgs/msg/Vector3"]
        for i in range(4):
            raw = store_types.serialize_cdr(
                twist(linear=vector(x=1.0, y=0.0, z=0.0), angular=vector(x=0.0, y=0.0, z=0.0)),
                "geometry_msgs/msg/Twist",
            )
            writer.write(connection, (1_714_557_600 + i) * 10**9, raw if i != 2 else raw[:9])
    store = open_store(Settings(db=store_url))
    try:
        report = import_rosbag(bag, store)
        assert (report.messages, report.samples, report.rejected) == (4, 3, 1)
        assert "/cmd_vel at 2024-05-01T10:00:02Z" in report.problems[0]
        [kept] = store.rejected("", 10, 0)
        assert kept["error"] == UNREADABLE and "geometry_msgs/msg/Twist" in kept["description"]
        again = import_rosbag(bag, store)
        assert again.complete_before and store.rejected_count() == 1
    finally:
        store.close()
