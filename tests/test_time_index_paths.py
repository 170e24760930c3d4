"""The robot's own time: a stamp inside an attribute's value becomes its samples' time index.

``TSDB_TIME_INDEX_PATHS`` (per attribute, optionally per entity type) and a
value path in ``Fiware-TimeIndex-Attribute`` (per subscription, through
Orion's ``httpCustom.headers``) come ahead of ``TimeInstant``,
``observedAt`` and the arrival time; a stamp that cannot be read falls back
and is counted on ``/metrics``.
"""

from __future__ import annotations

from datetime import UTC, datetime

import orjson
import pytest

from tests.support.cli import run_cli
from tsdb_service.core.errors import ParseError
from tsdb_service.core.timepaths import parse_time_paths
from tsdb_service.parse import parse_notification
from tsdb_service.parse.timeindex import read_stamp

RECEIVED = datetime(2030, 1, 1, 12, 0, tzinfo=UTC)
STAMP = {"sec": 1714557600, "nanosec": 123456789}  # 2024-05-01T10:00:00.123456789Z
AT_STAMP = datetime(2024, 5, 1, 10, 0, 0, 123456, tzinfo=UTC)
TIME_INSTANT = "2024-05-01T10:00:05.000Z"
AT_INSTANT = datetime(2024, 5, 1, 10, 0, 5, tzinfo=UTC)


def robot(**attrs) -> dict:
    return {
        "id": "urn:ngsiv2:ROS2System:R1",
        "type": "ROS2System",
        "TimeInstant": {"type": "DateTime", "value": TIME_INSTANT},
        **attrs,
    }


def ros(stamp) -> dict:
    return {"type": "Object", "value": {"header": {"stamp": stamp, "frame_id": "odom"}, "x": 1.5}}


def parse(entity: dict, rules: str = "", headers: dict | None = None):
    body = orjson.dumps({"subscriptionId": "s", "data": [entity]})
    return parse_notification(body, headers or {}, received_at=RECEIVED, time_paths=parse_time_paths(rules))


def times(samples) -> dict[str, datetime]:
    return {a.name: s.time_index for s in samples for a in s.attrs}


# --- stamps ---------------------------------------------------------------------


@pytest.mark.parametrize(
    "stamp, expected",
    [
        ({"sec": 1714557600, "nanosec": 123456789}, AT_STAMP),  # ROS 2 builtin_interfaces/Time
        ({"secs": 1714557600, "nsecs": 123456789}, AT_STAMP),  # ROS 1
        ({"sec": 1714557600, "nsec": 123456789}, AT_STAMP),  # Foxglove
        ("2024-05-01T10:00:00.123456Z", AT_STAMP),
        (1714557600.5, datetime(2024, 5, 1, 10, 0, 0, 500000, tzinfo=UTC)),
    ],
)
def test_a_stamp_is_read_in_every_robot_spelling(stamp, expected):
    assert read_stamp(stamp) == expected


@pytest.mark.parametrize(
    "stamp",
    [
        {"sec": 0, "nanosec": 0},  # the unset header of an unstamped message
        {"sec": 1714557600, "nanosec": 1_000_000_000},
        {"sec": 1714557600, "nanosec": -1},
        {"sec": True, "nanosec": 0},
        {"sec": 1714557600.5, "nanosec": 0},
        {"sec": 10**12, "nanosec": 0},
        {"sec": "1714557600", "nanosec": 0},
        "n/a",
        None,
        [],
    ],
)
def test_what_is_not_a_stamp(stamp):
    assert read_stamp(stamp) is None


# --- TSDB_TIME_INDEX_PATHS ------------------------------------------------------


def test_a_ruled_attribute_is_stored_at_its_stamp_and_the_rest_at_time_instant():
    samples = parse(robot(odom=ros(STAMP), battery={"type": "Number", "value": 0.8}), "odom=header.stamp")
    assert times(samples) == {"TimeInstant": AT_INSTANT, "battery": AT_INSTANT, "odom": AT_STAMP}
    [stamped] = [s for s in samples if s.time_index == AT_STAMP]
    assert stamped.entity_id == "urn:ngsiv2:ROS2System:R1" and stamped.entity_type == "ROS2System"
    assert stamped.attrs[0].observed_at == AT_STAMP  # an unchanged re-notification is then stored once


def test_attributes_with_the_same_stamp_share_one_row():
    samples = parse(robot(odom=ros(STAMP), fix=ros(STAMP)), "odom=header.stamp,fix=header.stamp")
    assert [sorted(a.name for a in s.attrs) for s in samples if s.time_index == AT_STAMP] == [["fix", "odom"]]


def test_a_rule_for_a_type_wins_over_the_any_type_rule_and_other_types_are_untouched():
    entity = robot(odom={"type": "Object", "value": {"stamp": STAMP, "header": {"stamp": {"sec": 1, "nanosec": 0}}}})
    assert times(parse(entity, "odom=header.stamp,ROS2System/odom=stamp"))["odom"] == AT_STAMP
    other = {**entity, "type": "Drone"}
    assert times(parse(other, "ROS2System/odom=stamp"))["odom"] == AT_INSTANT


def test_an_unreadable_stamp_falls_back_to_the_entity_time_and_is_counted(monkeypatch):
    from tsdb_service.parse import timeindex

    counted = []
    monkeypatch.setattr(timeindex, "on_stamp_fallback", lambda: counted.append(1))
    samples = parse(robot(odom=ros({"sec": 0, "nanosec": 0}), pose=ros("soon")), "odom=header.stamp,pose=header.stamp")
    assert times(samples) == {"TimeInstant": AT_INSTANT, "odom": AT_INSTANT, "pose": AT_INSTANT}
    assert len(counted) == 2
    assert all(a.observed_at is None for s in samples for a in s.attrs)


def test_an_entity_whose_every_attribute_has_its_stamp_is_not_a_fallback(monkeypatch):
    from tsdb_service.parse import timeindex

    fallbacks = []
    monkeypatch.setattr(timeindex, "on_fallback", lambda: fallbacks.append(1))
    entity = {"id": "R1", "type": "Robot", "odom": ros(STAMP)}
    [sample] = parse(entity, "odom=header.stamp")
    assert sample.time_index == AT_STAMP and not fallbacks


def test_an_ngsi_ld_property_is_timed_by_its_stamp_too():
    body = orjson.dumps(
        {
            "id": "urn:ngsi-ld:Notification:1",
            "type": "Notification",
            "data": [
                {"id": "urn:R1", "type": "Robot", "odom": {"type": "Property", "value": {"header": {"stamp": STAMP}}}}
            ],
        }
    )
    samples = parse_notification(body, {}, received_at=RECEIVED, time_paths=parse_time_paths("odom=header.stamp"))
    assert [s.time_index for s in samples] == [AT_STAMP]


@pytest.mark.parametrize(
    "spec, problem",
    [
        ("odom", "expected [TYPE/]ATTR=PATH"),
        ("odom=", "expected [TYPE/]ATTR=PATH"),
        ("od om=header.stamp", "is not an attribute name"),
        ("odom=header..stamp", "invalid value path"),
        ("odom=a,odom=b", "a second rule"),
    ],
)
def test_a_bad_setting_is_one_line_naming_the_flag(spec, problem):
    done = run_cli("serve", "--time-index-paths", spec, "--port", "1", env={"TSDB_DB": "/nonexistent/x.duckdb"})
    assert done.returncode == 2
    [line] = done.stderr.strip().splitlines()
    assert line.startswith("error: --time-index-paths (TSDB_TIME_INDEX_PATHS)") and problem in line


def test_an_mqtt_message_follows_the_same_rules():
    from tsdb_service.core.config import Settings
    from tsdb_service.ingest.mqtt.config import MqttConfig
    from tsdb_service.ingest.mqtt.messages import Message, parse_message

    config = MqttConfig.from_settings(
        Settings(mqtt_url="mqtt://127.0.0.1:1883", time_index_paths="ROS2System/odom=header.stamp")
    )
    payload = orjson.dumps({"subscriptionId": "s", "data": [robot(odom=ros(STAMP))]})
    samples = parse_message(Message("tsdb/robots", payload, 1, False, 1, b"", (), RECEIVED), config)
    assert times(samples) == {"TimeInstant": AT_INSTANT, "odom": AT_STAMP}


# --- Fiware-TimeIndex-Attribute with a value path ---------------------------------


def test_the_header_may_name_a_stamp_inside_an_attribute():
    samples = parse(
        robot(odom=ros(STAMP), battery={"type": "Number", "value": 0.8}),
        headers={"Fiware-TimeIndex-Attribute": "odom(header.stamp)"},
    )
    assert times(samples) == {"TimeInstant": AT_STAMP, "odom": AT_STAMP, "battery": AT_STAMP}


def test_the_header_stamp_that_cannot_be_read_falls_back_to_time_instant_and_is_counted(monkeypatch):
    from tsdb_service.parse import timeindex

    counted = []
    monkeypatch.setattr(timeindex, "on_stamp_fallback", lambda: counted.append(1))
    samples = parse(
        robot(odom=ros({"sec": 0, "nanosec": 0})), headers={"Fiware-TimeIndex-Attribute": "odom(header.stamp)"}
    )
    assert {s.time_index for s in samples} == {AT_INSTANT} and counted == [1]


@pytest.mark.parametrize("header", ["odom(header..stamp)", "odom(", "bad name(x)"])
def test_a_malformed_header_path_is_refused(header):
    with pytest.raises(ParseError, match="Fiware-TimeIndex-Attribute"):
        parse(robot(odom=ros(STAMP)), headers={"Fiware-TimeIndex-Attribute": header})


# --- through the service ------------------------------------------------------------


def test_stored_at_the_stamp_read_back_and_counted_on_metrics(client_factory, store_url, notify):
    entity = robot(odom=ros(STAMP), battery={"type": "Number", "value": 0.8})
    unstamped = robot(odom=ros({"sec": 0, "nanosec": 0}))
    unstamped["TimeInstant"]["value"] = "2024-05-01T10:00:06.000Z"
    headers = {"Fiware-Service": "robots"}
    with client_factory(store_url, time_index_paths="ROS2System/odom=header.stamp") as client:
        before = _stamp_fallbacks(client)
        for e in (entity, unstamped):
            notify(client, {"subscriptionId": "s", "data": [e]}, headers)
        odom = client.get("/v2/entities/urn:ngsiv2:ROS2System:R1/attrs/odom", headers=headers).json()
        assert odom["index"] == ["2024-05-01T10:00:00.123+00:00", "2024-05-01T10:00:06.000+00:00"]
        battery = client.get("/v2/entities/urn:ngsiv2:ROS2System:R1/attrs/battery", headers=headers).json()
        assert battery["index"] == ["2024-05-01T10:00:05.000+00:00"]
        assert _stamp_fallbacks(client) == before + 1


def _stamp_fallbacks(client) -> float:
    for line in client.get("/metrics").text.splitlines():
        if line.startswith("tsdb_time_index_stamp_fallbacks_total "):
            return float(line.split()[1])
    raise AssertionError("tsdb_time_index_stamp_fallbacks_total is not on /metrics")
