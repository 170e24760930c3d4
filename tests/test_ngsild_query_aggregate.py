"""format=aggregatedValues: every method, the type rules, and periods
(fixed, calendar, PT0S), computed in the database, on both backends."""

from __future__ import annotations

import pytest

from tests.ngsild_fixtures import B9211, ENTITIES, error_type, get, ld_notify
from tsdb_service.faces.ngsild.aggregate import add_months, boundaries
from tsdb_service.faces.ngsild.params import parse_duration

ALL = "totalCount,distinctCount,sum,avg,min,max,stddev,sumsq"


def store(client, attr: str, values: list, times: list[str], attr_type: str = "Property") -> None:
    member = {"Property": "value", "Relationship": "object"}[attr_type]
    for value, at in zip(values, times, strict=True):
        ld_notify(
            client, [{"id": B9211, "type": "Vehicle", attr: {"type": attr_type, member: value, "observedAt": at}}]
        )


def agg(client, attr: str, methods: str = ALL, status: int = 200, **params):
    response = get(
        client,
        path=f"{ENTITIES}/{B9211}",
        status=status,
        params={"format": "aggregatedValues", "aggrMethods": methods, "attrs": attr, **params},
    )
    return response.json() if status == 200 else response


HOURS = ["2024-01-01T00:10:00Z", "2024-01-01T00:50:00Z", "2024-01-01T01:20:00Z", "2024-01-01T03:05:00Z"]


def test_numbers_hourly_from_time_at(client):
    store(client, "speed", [1, 3, 4, 4], HOURS)
    got = agg(client, "speed", aggrPeriodDuration="PT1H", timerel="after", timeAt="2024-01-01T00:00:00Z")["speed"]
    assert got["type"] == "Property"
    assert got["totalCount"] == [
        [2, "2024-01-01T00:00:00Z", "2024-01-01T01:00:00Z"],
        [1, "2024-01-01T01:00:00Z", "2024-01-01T02:00:00Z"],
        [1, "2024-01-01T03:00:00Z", "2024-01-01T04:00:00Z"],
    ]  # no empty period
    assert [v for v, _, _ in got["sum"]] == [4, 4, 4]
    assert [v for v, _, _ in got["avg"]] == [2.0, 4.0, 4.0]
    assert [v for v, _, _ in got["min"]] == [1, 4, 4] and [v for v, _, _ in got["max"]] == [3, 4, 4]
    assert [v for v, _, _ in got["stddev"]] == [1.0, 0.0, 0.0]  # population
    assert [v for v, _, _ in got["sumsq"]] == [10, 16, 16]
    assert [v for v, _, _ in got["distinctCount"]] == [2, 1, 1]


def test_a_period_mixing_integers_and_decimals_is_one_period(client):
    """Integers and decimals are separate groups in the statement; a period
    holding both is merged into one, and only an all-integer period keeps
    integer min/max."""
    times = ["2024-01-01T00:10:00Z", "2024-01-01T00:20:00Z", "2024-01-01T00:30:00Z"]
    store(client, "speed", [2, 2.5, 3, 1, 5], [*times, "2024-01-01T01:10:00Z", "2024-01-01T01:20:00Z"])
    got = agg(client, "speed", aggrPeriodDuration="PT1H", timerel="after", timeAt="2024-01-01T00:00:00Z")["speed"]
    assert [v for v, _, _ in got["totalCount"]] == [3, 2]
    assert [v for v, _, _ in got["distinctCount"]] == [3, 2]
    assert [v for v, _, _ in got["sum"]] == [7.5, 6]
    assert [v for v, _, _ in got["avg"]] == [2.5, 3.0]
    assert [v for v, _, _ in got["sumsq"]] == [19.25, 26]
    (mixed_min, _, _), (int_min, _, _) = got["min"]
    (mixed_max, _, _), (int_max, _, _) = got["max"]
    assert (mixed_min, mixed_max, int_min, int_max) == (2, 3, 1, 5)
    assert isinstance(mixed_max, float) and isinstance(int_min, int) and isinstance(int_max, int)


def test_whole_range_and_first_instance_start(client):
    store(client, "speed", [1, 3, 4, 4], HOURS)
    whole = agg(client, "speed", "avg,distinctCount", aggrPeriodDuration="PT0S")["speed"]
    assert whole["avg"] == [[3.0, "2024-01-01T00:10:00Z", "2024-01-01T03:05:00Z"]]
    assert whole["distinctCount"][0][0] == 3
    window = agg(
        client, "speed", "max", timerel="between", timeAt="2024-01-01T00:00:00Z", endTimeAt="2024-01-01T02:00:00Z"
    )["speed"]
    assert window["max"] == [[4, "2024-01-01T00:00:00Z", "2024-01-01T02:00:00Z"]]
    before = agg(
        client, "speed", "totalCount", aggrPeriodDuration="PT2H", timerel="before", timeAt="2024-01-02T00:00:00Z"
    )["speed"]
    assert before["totalCount"] == [
        [3, "2024-01-01T00:10:00Z", "2024-01-01T02:10:00Z"],
        [1, "2024-01-01T02:10:00Z", "2024-01-01T04:10:00Z"],
    ]


def test_calendar_periods(client):
    times = ["2024-01-31T10:00:00Z", "2024-02-15T00:00:00Z", "2024-03-01T00:00:00Z", "2025-02-01T00:00:00Z"]
    store(client, "speed", [1, 2, 3, 4], times)
    monthly = agg(client, "speed", "sum", aggrPeriodDuration="P1M", timerel="after", timeAt="2024-01-31T00:00:00Z")[
        "speed"
    ]["sum"]
    assert monthly[:2] == [
        [3, "2024-01-31T00:00:00Z", "2024-02-29T00:00:00Z"],
        [3, "2024-02-29T00:00:00Z", "2024-03-31T00:00:00Z"],
    ]
    yearly = agg(
        client, "speed", "totalCount", aggrPeriodDuration="P1Y", timerel="after", timeAt="2024-01-01T00:00:00Z"
    )["speed"]["totalCount"]
    assert yearly == [
        [3, "2024-01-01T00:00:00Z", "2025-01-01T00:00:00Z"],
        [1, "2025-01-01T00:00:00Z", "2026-01-01T00:00:00Z"],
    ]
    weekly = agg(
        client, "speed", "totalCount", aggrPeriodDuration="P1W", timerel="after", timeAt="2024-01-29T00:00:00Z"
    )["speed"]["totalCount"]
    assert weekly[0] == [1, "2024-01-29T00:00:00Z", "2024-02-05T00:00:00Z"]


def test_type_rules(client):
    times = HOURS[:3]
    store(client, "flag", [True, False, True], times)
    store(client, "label", ["b", "a", "c"], times)
    store(client, "sizes", [[1], [1, 2, 3], [1, 2]], times)
    store(client, "owner", ["urn:a", "urn:b", "urn:a"], times, "Relationship")
    flags = agg(client, "flag", "sum,avg,min,max")["flag"]
    assert [flags[m][0][0] for m in ("sum", "min", "max")] == [2, 0, 1] and flags["avg"][0][0] == pytest.approx(2 / 3)
    labels = agg(client, "label", "min,max,distinctCount")["label"]
    assert [labels[m][0][0] for m in ("min", "max", "distinctCount")] == ["a", "c", 3]
    sizes = agg(client, "sizes", "min,max,sum,avg")["sizes"]
    assert [sizes[m][0][0] for m in ("min", "max", "sum", "avg")] == [1, 3, 6, 2.0]
    owner = agg(client, "owner", "totalCount,distinctCount")["owner"]
    assert owner["type"] == "Relationship" and [owner[m][0][0] for m in ("totalCount", "distinctCount")] == [3, 2]
    # Clause 4.5.19, 6.19/6.20: a method that does not apply to an attribute's
    # values answers null for its periods, never a 400 for the whole request.
    for attr, method in [("label", "sum"), ("label", "avg"), ("owner", "max"), ("label", "stddev")]:
        assert agg(client, attr, method)[attr][method] == [[None, HOURS[0], HOURS[2]]]


def test_datetime_values(client, notify):
    for value, at in [
        ("2024-01-01T00:00:00Z", "2024-01-01T00:10:00Z"),
        ("2024-01-01T02:00:00Z", "2024-01-01T00:50:00Z"),
    ]:
        notify(
            client,
            {
                "subscriptionId": "s",
                "data": [
                    {
                        "id": B9211,
                        "type": "Vehicle",
                        "lastSeen": {"type": "DateTime", "value": value},
                        "TimeInstant": {"type": "DateTime", "value": at},
                    }
                ],
            },
            {"Fiware-Service": "fleet"},
        )
    got = agg(client, "lastSeen", "min,max,avg,totalCount")["lastSeen"]
    assert [got[m][0][0] for m in ("min", "max", "avg", "totalCount")] == [
        "2024-01-01T00:00:00Z",
        "2024-01-01T02:00:00Z",
        "2024-01-01T01:00:00Z",
        2,
    ]
    assert [value for value, _, _ in agg(client, "lastSeen", "sum")["lastSeen"]["sum"]] == [None]


def test_aggregation_needs_methods(client):
    store(client, "speed", [1], HOURS[:1])
    assert (
        error_type(get(client, path=f"{ENTITIES}/{B9211}", params={"format": "aggregatedValues"}, status=400))
        == "BadRequestData"
    )


def test_calendar_arithmetic():
    from datetime import UTC, datetime

    assert add_months(datetime(2024, 1, 31, tzinfo=UTC), 1) == datetime(2024, 2, 29, tzinfo=UTC)
    edges = boundaries(datetime(2024, 1, 31, tzinfo=UTC), datetime(2024, 4, 1, tzinfo=UTC), parse_duration("P1M"))
    assert len(edges) == 4  # Jan 31, Feb 29, Mar 31, Apr 30


def test_one_statement_per_request(client):
    """The periods' start (no timerel: the first instance) and each
    attribute's type come from the one grouped statement: no extra round trip."""
    store(client, "speed", [1, 3, 4, 4], HOURS)
    querier = client.app.state.store.querier()
    statements: list[str] = []
    fetch = querier._fetch

    def counting(sql, params, *args, **kwargs):
        statements.append(sql)
        return fetch(sql, params, *args, **kwargs)

    querier._fetch = counting
    try:
        got = agg(client, "speed", "avg,max", aggrPeriodDuration="PT2H")["speed"]
    finally:
        del querier._fetch
    assert got["type"] == "Property"
    assert got["max"] == [
        [4, "2024-01-01T00:10:00Z", "2024-01-01T02:10:00Z"],
        [4, "2024-01-01T02:10:00Z", "2024-01-01T04:10:00Z"],
    ]
    assert [v for v, _, _ in got["avg"]] == [8 / 3, 4.0]
    on_samples = [sql for sql in statements if "samples" in sql]
    assert len(on_samples) == 1 and "GROUP BY" in on_samples[0] and "DISTINCT" not in on_samples[0], statements
