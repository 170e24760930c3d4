"""Time parsing and the time-index rules, in order."""

from __future__ import annotations

from datetime import UTC, datetime, timedelta, timezone

import orjson
import pytest

from tsdb_service.parse import parse_notification
from tsdb_service.parse.timeindex import parse_time

UTC = UTC
RECEIVED = datetime(2030, 1, 1, 12, 0, tzinfo=UTC)


def utc(*args):
    return datetime(*args, tzinfo=UTC)


def index_of(entity, headers=None, received_at=RECEIVED, fmt="normalized"):
    body = orjson.dumps({"subscriptionId": "s", "data": [{"id": "E1", "type": "T", **entity}]})
    hdrs = {"Ngsiv2-AttrsFormat": fmt, **(headers or {})}
    [sample] = parse_notification(body, hdrs, received_at=received_at)
    return sample.time_index


def ld_index_of(entity, received_at=RECEIVED):
    body = orjson.dumps({"id": "urn:n", "type": "Notification", "data": [{"id": "urn:e", "type": "T", **entity}]})
    [sample] = parse_notification(body, {}, received_at=received_at)
    return sample.time_index


def dt(value):
    return {"type": "DateTime", "value": value}


# --- parse_time -------------------------------------------------------------------


@pytest.mark.parametrize(
    "text, expected",
    [
        ("2024-05-01T10:00:00Z", utc(2024, 5, 1, 10)),
        ("2024-05-01T10:00:00z", utc(2024, 5, 1, 10)),
        ("2024-05-01T10:00:00+02:00", utc(2024, 5, 1, 8)),
        ("2024-05-01T10:00:00-05:30", utc(2024, 5, 1, 15, 30)),
        ("2024-05-01T10:00:00.5Z", utc(2024, 5, 1, 10, 0, 0, 500000)),
        ("2024-05-01T10:00:00.123456789Z", utc(2024, 5, 1, 10, 0, 0, 123456)),
        ("2024-05-01T10:00:00.1234567+01:00", utc(2024, 5, 1, 9, 0, 0, 123456)),
        ("2024-05-01T10:00:00", utc(2024, 5, 1, 10)),
        ("2024-05-01 10:00:00", utc(2024, 5, 1, 10)),
        ("2024-05-01T10:00Z", utc(2024, 5, 1, 10)),
        ("2024-05-01", utc(2024, 5, 1)),
        ("2024-05-01T00:30:00+01:00", utc(2024, 4, 30, 23, 30)),
    ],
)
def test_parse_iso(text, expected):
    parsed = parse_time(text)
    assert parsed == expected
    assert parsed.tzinfo == UTC


@pytest.mark.parametrize(
    "text",
    [
        "5",
        "12",
        "1714557600",
        "2024",
        "2024-05",
        "20240501T100000Z",
        "2024-13-01",
        "2024-02-30",
        "2024-05-01T25:00:00",
        "2024-05-01Tnope",
        "2024-05-01X10:00",
        "0000-01-01",
        "0001-01-01T00:00:00+01:00",
        "9999-12-31T23:00:00-02:00",
        "٢٠٢٤-05-01",
        "hello",
        "",
        "2024-W18-3",
    ],
)
def test_parse_rejects(text):
    assert parse_time(text) is None


def test_epoch_seconds_and_millis():
    assert parse_time(1714557600) == utc(2024, 5, 1, 10)
    assert parse_time(1714557600.25) == utc(2024, 5, 1, 10, 0, 0, 250000)
    assert parse_time(1714557600123) == utc(2024, 5, 1, 10, 0, 0, 123000)
    assert parse_time(0) == utc(1970, 1, 1)
    assert parse_time(5) == utc(1970, 1, 1, 0, 0, 5)


@pytest.mark.parametrize("value", [True, False, None, [1], {"a": 1}, 1e30, -1e30, float("nan"), float("inf")])
def test_parse_time_other_values(value):
    assert parse_time(value) is None


def test_ld_typed_literal():
    assert parse_time({"@type": "DateTime", "@value": "2024-05-01T10:00:00Z"}) == utc(2024, 5, 1, 10)


# --- rules, in order -------------------------------------------------------------


FULL = {
    "custom": dt("2021-01-01T00:00:00Z"),
    "TimeInstant": dt("2022-01-01T00:00:00Z"),
    "timestamp": dt("2023-01-01T00:00:00Z"),
    "dateModified": dt("2024-01-01T00:00:00Z"),
    "temp": {"type": "Number", "value": 1, "metadata": {"TimeInstant": dt("2025-01-01T00:00:00Z")}},
}


def test_rule1_header_attribute_wins():
    assert index_of(FULL, {"Fiware-TimeIndex-Attribute": "custom"}) == utc(2021, 1, 1)


def test_rule1_header_attribute_in_key_values():
    entity = {"custom": "2021-06-01T00:00:00Z", "TimeInstant": "2022-01-01T00:00:00Z"}
    assert index_of(entity, {"fiware-timeindex-attribute": "custom"}, fmt="keyValues") == utc(2021, 6, 1)


def test_rule1_invalid_header_attribute_falls_through():
    entity = {**FULL, "custom": {"type": "Text", "value": "5"}}
    assert index_of(entity, {"Fiware-TimeIndex-Attribute": "custom"}) == utc(2022, 1, 1)
    assert index_of(FULL, {"Fiware-TimeIndex-Attribute": "missing"}) == utc(2022, 1, 1)


def test_rule2_time_instant_attribute():
    assert index_of(FULL) == utc(2022, 1, 1)


def test_rule2_time_instant_metadata_newest_wins():
    entity = {
        "a": {"type": "Number", "value": 1, "metadata": {"TimeInstant": dt("2025-01-01T00:00:00Z")}},
        "b": {"type": "Number", "value": 2, "metadata": {"TimeInstant": dt("2025-03-01T00:00:00Z")}},
        "c": {"type": "Number", "value": 3, "metadata": {"TimeInstant": dt("garbage")}},
        "timestamp": dt("2023-01-01T00:00:00Z"),
    }
    assert index_of(entity) == utc(2025, 3, 1)


def test_rule2_invalid_attribute_falls_to_metadata():
    entity = {
        "TimeInstant": {"type": "Text", "value": "5"},
        "a": {"type": "Number", "value": 1, "metadata": {"TimeInstant": dt("2025-01-01T00:00:00Z")}},
    }
    assert index_of(entity) == utc(2025, 1, 1)


def test_rule3_timestamp():
    entity = {"timestamp": dt("2023-01-01T00:00:00+02:00"), "dateModified": dt("2024-01-01T00:00:00Z")}
    assert index_of(entity) == utc(2022, 12, 31, 22)


def test_rule3_timestamp_epoch_seconds_and_millis():
    assert index_of({"timestamp": 1714557600}, fmt="keyValues") == utc(2024, 5, 1, 10)
    assert index_of({"timestamp": 1714557600500}, fmt="keyValues") == utc(2024, 5, 1, 10, 0, 0, 500000)


def test_lone_number_string_is_not_a_time():
    assert index_of({"TimeInstant": "5", "timestamp": "12"}, fmt="keyValues") == RECEIVED


def test_rule4_newest_observed_at():
    entity = {
        "a": {"type": "Property", "value": 1, "observedAt": "2024-01-01T00:00:00Z"},
        "b": {"type": "Property", "value": 2, "observedAt": "2024-02-01T00:00:00+01:00"},
        "modifiedAt": "2029-01-01T00:00:00Z",
    }
    assert ld_index_of(entity) == utc(2024, 1, 31, 23)


def test_rule4_observed_at_in_multi_instance():
    entity = {
        "a": [
            {"type": "Property", "value": 1, "observedAt": "2024-01-01T00:00:00Z"},
            {"type": "Property", "value": 2, "datasetId": "urn:d", "observedAt": "2024-03-01T00:00:00Z"},
        ]
    }
    assert ld_index_of(entity) == utc(2024, 3, 1)


def test_ld_time_instant_beats_observed_at():
    entity = {
        "TimeInstant": {"type": "Property", "value": "2020-01-01T00:00:00Z"},
        "a": {"type": "Property", "value": 1, "observedAt": "2024-01-01T00:00:00Z"},
    }
    assert ld_index_of(entity) == utc(2020, 1, 1)


def test_rule5_modified_at():
    entity = {
        "a": {"type": "Property", "value": 1},
        "modifiedAt": "2024-04-01T00:00:00Z",
        "createdAt": "2020-01-01T00:00:00Z",
    }
    assert ld_index_of(entity) == utc(2024, 4, 1)


def test_rule6_date_modified_attribute_then_metadata():
    assert index_of({"dateModified": dt("2024-01-01T00:00:00Z")}) == utc(2024, 1, 1)
    entity = {
        "a": {"type": "Number", "value": 1, "metadata": {"dateModified": dt("2024-01-01T00:00:00Z")}},
        "b": {"type": "Number", "value": 1, "metadata": {"dateModified": dt("2024-02-01T00:00:00Z")}},
    }
    assert index_of(entity) == utc(2024, 2, 1)


def test_rule7_reception_time_is_utc():
    paris = timezone(timedelta(hours=2))
    received = datetime(2030, 1, 1, 14, 0, tzinfo=paris)
    result = index_of({"a": {"type": "Number", "value": 1}}, received_at=received)
    assert result == utc(2030, 1, 1, 12)
    assert result.tzinfo == UTC


def test_rule7_naive_reception_time_taken_as_utc():
    result = index_of({"a": {"type": "Number", "value": 1}}, received_at=datetime(2030, 1, 1))
    assert result == utc(2030, 1, 1)


def test_time_index_shared_per_entity_not_per_notification():
    body = orjson.dumps(
        {
            "subscriptionId": "s",
            "data": [
                {"id": "A", "type": "T", "TimeInstant": dt("2024-01-01T00:00:00Z")},
                {"id": "B", "type": "T", "x": {"type": "Number", "value": 1}},
            ],
        }
    )
    a, b = parse_notification(body, {"Ngsiv2-AttrsFormat": "normalized"}, received_at=RECEIVED)
    assert a.time_index == utc(2024, 1, 1)
    assert b.time_index == RECEIVED
