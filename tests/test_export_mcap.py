"""``export --format mcap``: history as an MCAP file that Foxglove opens, read back with the ``mcap`` reader.

One channel per entity and attribute, JSON messages with a JSON Schema per
channel, log time = the sample's time, ``foxglove.LocationFix`` for
positions; every value equal to what the store holds (the Parquet export
of the same selection is the reference). An exported file imports back
into the same series.
"""

from __future__ import annotations

import io
import math

import orjson
import pyarrow.parquet as pq
import pytest
from mcap.reader import make_reader

from tests.support.rosbags import write_bag
from tsdb_service.commands.rosbag.importer import import_rosbag
from tsdb_service.core.config import Settings
from tsdb_service.storage import open_store

HEADERS = {"Fiware-Service": "robots"}
NOTIFIED = [
    {
        "id": "urn:ngsiv2:Robot:R2",
        "type": "Robot",
        "TimeInstant": {"type": "DateTime", "value": f"2024-05-01T11:00:0{i}.123Z"},
        "speed": {"type": "Number", "value": 0.5 * i},
        "mode": {"type": "Text", "value": "=cut" if i else "idle"},
        "docked": {"type": "Boolean", "value": i == 0},
        "position": {"type": "geo:point", "value": f"48.1{i}, 11.5{i}"},
        "zone": {
            "type": "geo:json",
            "value": {"type": "Polygon", "coordinates": [[[11.5, 48.1], [11.6, 48.1], [11.6, 48.2], [11.5, 48.1]]]},
        },
        "status": {"type": "StructuredValue", "value": {"value": i}} if i < 2 else {"type": "Number", "value": 7},
    }
    for i in range(3)
]
MAP = "service: robots\ntopics:\n  /fix: {attributes: {location: {path: '', type: 'geo:json'}}}\n"


@pytest.fixture
def loaded(tmp_path, store_url, client_factory, notify):
    bag = tmp_path / "run"
    write_bag(bag, "mcap", count=4)
    (tmp_path / "map.yaml").write_text(MAP)
    store = open_store(Settings(db=store_url))
    try:
        from tsdb_service.commands.rosbag.mapping import load_map

        import_rosbag(bag, store, spec=load_map(tmp_path / "map.yaml"), defaults={"service": "robots"})
    finally:
        store.close()
    with client_factory(store_url) as client:
        for entity in NOTIFIED:
            notify(client, {"subscriptionId": "s", "data": [entity]}, HEADERS)
        yield client


def _reference(client) -> list[dict]:
    answer = client.get("/v2/export", params={"format": "parquet"}, headers=HEADERS)
    return pq.read_table(io.BytesIO(answer.content)).to_pylist()


def _value(row: dict):
    if row["value_json"] is not None:
        return orjson.loads(row["value_json"])
    for column in ("value_number", "value_text", "value_bool"):
        if row[column] is not None:
            return row[column]
    return None


def _read(data: bytes):
    reader = make_reader(io.BytesIO(data))
    summary = reader.get_summary()
    messages = [(channel, message) for _, channel, message in reader.iter_messages(log_time_order=True)]
    return summary, messages


def test_every_sample_is_a_message_on_its_channel_at_its_time(loaded):
    answer = loaded.get("/v2/export", params={"format": "mcap"}, headers=HEADERS)
    assert answer.status_code == 200 and answer.headers["content-type"] == "application/x-mcap"
    assert 'filename="tsdb-export.mcap"' in answer.headers["content-disposition"]
    summary, messages = _read(answer.content)
    reference = _reference(loaded)
    assert len(messages) == len(reference)
    for row, (channel, message) in zip(reference, messages, strict=True):
        path = "" if row["service_path"] == "/" else row["service_path"]
        assert channel.topic == f"{path}/{row['entity_id']}/{row['attribute']}"
        assert channel.message_encoding == "json"
        assert channel.metadata["tsdb.entity_type"] == row["entity_type"]
        assert channel.metadata["tsdb.ngsi_type"] == (row["ngsi_type"] or "")
        assert channel.metadata["tsdb.service"] == "robots"
        micros = int(row["time"].timestamp()) * 1_000_000 + row["time"].microsecond
        assert message.log_time == message.publish_time == micros * 1000
        schema = summary.schemas[channel.schema_id]
        assert schema.encoding == "jsonschema" and orjson.loads(schema.data)["type"] == "object"
        _same_value(schema.name, orjson.loads(message.data), _value(row), row)


def _same_value(schema: str, message: dict, value, row: dict) -> None:
    if schema == "foxglove.LocationFix":
        point = value if isinstance(value, dict) else None
        if point is None:  # geo:point "lat, lon"
            lat, lon = (float(x) for x in value.split(","))
        else:
            lon, lat = point["coordinates"][:2]
        assert (message["latitude"], message["longitude"]) == (pytest.approx(lat), pytest.approx(lon))
        assert message["metadata"] == [{"key": "ngsi_value", "value": row["value_json"]}]
        assert set(message) >= {"timestamp", "frame_id", "altitude", "position_covariance", "position_covariance_type"}
        return
    if schema == "foxglove.GeoJSON":
        assert orjson.loads(message["ngsi_value"]) == value and orjson.loads(message["geojson"])["type"] == "Polygon"
        return
    if isinstance(value, dict) and set(value) != {"value"}:
        assert message == value  # a ROS message leaves as itself
        return
    assert message == {"value": value}


def test_positions_are_location_fixes_and_ros_messages_keep_their_shape(loaded):
    summary, messages = _read(loaded.get("/v2/export", params={"format": "mcap"}, headers=HEADERS).content)
    by_topic = {c.topic: summary.schemas[c.schema_id].name for c in summary.channels.values()}
    assert by_topic["/urn:ngsi-ld:ROS2Topic:fix/location"] == "foxglove.LocationFix"
    assert by_topic["/urn:ngsiv2:Robot:R2/position"] == "foxglove.LocationFix"
    assert by_topic["/urn:ngsiv2:Robot:R2/zone"] == "foxglove.GeoJSON"
    assert by_topic["/urn:ngsiv2:Robot:R2/speed"] == "tsdb.Number"
    assert by_topic["/urn:ngsi-ld:ROS2Topic:odom/odom"] == "tsdb.Object"
    schema = next(s for s in summary.schemas.values() if s.name == "tsdb.Object" and b"twist" in s.data)
    twist = orjson.loads(schema.data)["properties"]["twist"]["properties"]["twist"]
    assert twist["properties"]["linear"]["properties"]["x"] == {"type": "number"}
    # a status that changed shape: one channel per shape, on the same topic
    status = [c for c in summary.channels.values() if c.topic == "/urn:ngsiv2:Robot:R2/status"]
    assert len(status) == 2
    fixes = [orjson.loads(m.data) for c, m in messages if c.topic.endswith("fix/location")]
    assert all(math.isfinite(f["latitude"]) and f["timestamp"]["sec"] > 0 for f in fixes)


def test_the_command_writes_the_same_file_and_it_imports_back(loaded, tmp_path, store_url, backend):
    from tsdb_service.cli.main import main

    out = tmp_path / "robots.mcap"
    loaded.app.state.store.sync()
    if backend == "duckdb":  # the file belongs to the running app: export through it instead
        data = loaded.get("/v2/export", params={"format": "mcap"}, headers=HEADERS).content
        out.write_bytes(data)
    else:
        assert main(["export", "--db", store_url, "--service", "robots", "--out", str(out)]) == 0
    reference = sorted((r["entity_id"], r["attribute"], r["time"], orjson.dumps(_value(r))) for r in _reference(loaded))
    again = str(tmp_path / "again.duckdb")
    target = open_store(Settings(db=again))
    try:
        report = import_rosbag(out, target)
        assert report.messages == len(reference) and report.rejected == 0
        from tsdb_service.faces.export import ExportQuery, export_query, open_export

        query: ExportQuery = export_query({"format": "parquet"}, {"fiware-service": "robots"}, "robots")
        with open_export(target, query) as stream:
            rows = [row for batch in iter(stream.next_batch, None) for row in batch.to_pylist()]
    finally:
        target.close()
    back = sorted((r["entity_id"], r["attribute"], r["time"], orjson.dumps(_value(r))) for r in rows)
    assert back == reference


def test_mcap_exports_samples_not_buckets(loaded):
    answer = loaded.get("/v2/export", params={"format": "mcap", "bucket": "1h"}, headers=HEADERS)
    assert answer.status_code == 400 and "mcap exports the samples themselves" in answer.json()["description"]
