"""A time index that cannot be a time: still the reception time, but recorded.

Before: year 0, year 99999, epoch 1e20 or a boolean silently became the
reception time, and the seconds/milliseconds switch read seconds of the year
10000 as a 1978 instant in milliseconds. Now the fallback is kept, each
sample of such an entity carries ``timeIndexFallback`` metadata naming the
unusable sources, the Prometheus counter counts it, and epoch numbers below
10^12 are seconds (every second of the years 1..9999 is), so no instant in
those years is misread.
"""

from __future__ import annotations

import re
from datetime import UTC, datetime, timedelta

import orjson
import pytest

from tsdb_service.parse import parse_notification
from tsdb_service.parse.timeindex import FALLBACK_METADATA, parse_time

UTC = UTC
RECEIVED = datetime(2030, 1, 1, 12, 0, tzinfo=UTC)
EPOCH = datetime(1970, 1, 1, tzinfo=UTC)
LAST_SECOND_OF_9999 = 253402300799
FIRST_SECOND_OF_YEAR_1 = -62135596800


def parse(entity: dict, headers: dict | None = None):
    body = orjson.dumps({"subscriptionId": "s", "data": [{"id": "E1", "type": "T", **entity}]})
    [sample] = parse_notification(body, {"Ngsiv2-AttrsFormat": "normalized", **(headers or {})}, received_at=RECEIVED)
    return sample


def flags(sample) -> list[list[str] | None]:
    out = []
    for attr in sample.attrs:
        md = orjson.loads(attr.md) if attr.md else {}
        out.append(md.get(FALLBACK_METADATA, {}).get("value"))
    return out


# --- the unit rule ----------------------------------------------------------------------


@pytest.mark.parametrize(
    ("number", "expected"),
    [
        (LAST_SECOND_OF_9999, datetime(9999, 12, 31, 23, 59, 59, tzinfo=UTC)),
        (FIRST_SECOND_OF_YEAR_1, datetime(1, 1, 1, tzinfo=UTC)),
        (1e11, EPOCH + timedelta(seconds=1e11)),  # the year 5138 in seconds; was read as 1973 in ms
        (2.5e11, EPOCH + timedelta(seconds=2.5e11)),
        (1_000_000_000, datetime(2001, 9, 9, 1, 46, 40, tzinfo=UTC)),
        (1e12, datetime(2001, 9, 9, 1, 46, 40, tzinfo=UTC)),  # from here on milliseconds
        (1714557600123, datetime(2024, 5, 1, 10, 0, 0, 123000, tzinfo=UTC)),
        (-1e12, datetime(1938, 4, 24, 22, 13, 20, tzinfo=UTC)),
    ],
)
def test_epoch_numbers(number, expected):
    assert parse_time(number) == expected


@pytest.mark.parametrize(
    "number", [LAST_SECOND_OF_9999 + 1, 9e11, 999_999_999_999, FIRST_SECOND_OF_YEAR_1 - 1, 1e20, -1e20, 2.6e14]
)
def test_numbers_that_are_no_instant(number):
    # LAST_SECOND_OF_9999 + 1 (the year 10000 in seconds) was read as 1978.
    assert parse_time(number) is None


def test_every_year_in_seconds_is_read_as_seconds():
    for year in range(1, 10000, 7):
        moment = datetime(year, 6, 30, 12, tzinfo=UTC)
        assert parse_time((moment - EPOCH).total_seconds()) == moment


# --- the fallback is recorded ------------------------------------------------------------


@pytest.mark.parametrize(
    "bad",
    [
        "0000-01-01T00:00:00Z",
        "99999-01-01T00:00:00Z",
        "+099999-01-01",
        1e20,
        True,
        LAST_SECOND_OF_9999 + 1,
        "n/a",
        "2024-13-45",
    ],
)
def test_unusable_time_instant_is_recorded_on_every_sample(bad):
    sample = parse({"TimeInstant": {"type": "DateTime", "value": bad}, "x": {"type": "Number", "value": 1}})
    assert sample.time_index == RECEIVED
    assert flags(sample) == [["TimeInstant"], ["TimeInstant"]]


def test_each_unusable_source_is_named_and_metadata_kept():
    sample = parse(
        {
            "x": {
                "type": "Number",
                "value": 1,
                "metadata": {
                    "TimeInstant": {"type": "DateTime", "value": False},
                    "unit": {"type": "Text", "value": "m"},
                },
            },
            "timestamp": {"type": "Number", "value": 1e20},
            "when": {"type": "Text", "value": "never"},
        },
        headers={"Fiware-TimeIndex-Attribute": "when"},
    )
    assert sample.time_index == RECEIVED
    md = orjson.loads(sample.attrs[0].md)
    assert md["unit"] == {"type": "Text", "value": "m"}
    assert md[FALLBACK_METADATA]["value"] == ["when", "TimeInstant metadata", "timestamp"]


def test_no_time_at_all_is_not_flagged():
    sample = parse({"x": {"type": "Number", "value": 1}})
    assert sample.time_index == RECEIVED and flags(sample) == [None]


def test_a_later_usable_source_is_not_a_fallback():
    sample = parse(
        {
            "TimeInstant": {"type": "DateTime", "value": True},
            "dateModified": {"type": "DateTime", "value": "2024-05-01T10:00:00Z"},
        }
    )
    assert sample.time_index == datetime(2024, 5, 1, 10, tzinfo=UTC)
    assert flags(sample) == [None, None]


def test_ngsi_ld_observed_at_year_zero():
    body = orjson.dumps(
        {
            "id": "urn:n",
            "type": "Notification",
            "data": [
                {
                    "id": "urn:E",
                    "type": "T",
                    "p": {"type": "Property", "value": 1, "observedAt": "0000-01-01T00:00:00Z"},
                }
            ],
        }
    )
    [sample] = parse_notification(body, {}, received_at=RECEIVED)
    assert sample.time_index == RECEIVED
    md = orjson.loads(sample.attrs[0].md)
    assert md["observedAt"] == "0000-01-01T00:00:00Z"
    assert md[FALLBACK_METADATA]["value"] == ["observedAt"]


# --- over HTTP, stored, counted ----------------------------------------------------------------


def _fallbacks(client) -> float:
    text = client.get("/metrics").text
    match = re.search(r"^tsdb_time_index_fallbacks_total (\S+)$", text, re.M)
    return float(match.group(1))


def test_stored_with_the_flag_and_counted(client):
    before = _fallbacks(client)
    body = {
        "subscriptionId": "s",
        "data": [
            {
                "id": "E1",
                "type": "T",
                "TimeInstant": {"type": "DateTime", "value": "0000-01-01T00:00:00Z"},
                "x": {"type": "Number", "value": 1},
            },
            {
                "id": "E2",
                "type": "T",
                "TimeInstant": {"type": "DateTime", "value": "2024-05-01T10:00:00Z"},
                "x": {"type": "Number", "value": 2},
            },
        ],
    }
    assert client.post("/v2/notify", json=body).status_code == 200
    assert _fallbacks(client) == before + 1
    store = client.app.state.store
    rows = store.querier()._fetch(
        "SELECT s.entity_id, s.attr, x.md FROM samples_all x JOIN series s ON s.sid = x.sid "
        "ORDER BY s.entity_id, s.attr",
        [],
    )
    got = {(eid, attr): (orjson.loads(md) if md else {}).get(FALLBACK_METADATA) for eid, attr, md in rows}
    flag = {"type": "StructuredValue", "value": ["TimeInstant"]}
    assert got == {("E1", "TimeInstant"): flag, ("E1", "x"): flag, ("E2", "TimeInstant"): None, ("E2", "x"): None}
    # The samples are readable, at the reception time, with their values as sent.
    history = client.get("/v2/entities/E1").json()
    assert [a["values"] for a in history["attributes"]] == [["0000-01-01T00:00:00Z"], [1]]
