"""Where fixed aggregation periods start when the window has no start: at
the first instance, with or without observedAt, before the window's end
(PostgreSQL finds it by index probes, ``PostgresQuerier._origin``).
Instance times read back to the microsecond across the range where
PostgreSQL's float epoch is exact and beyond it."""

from __future__ import annotations

import pytest

from tests.ngsild_fixtures import B9211, ENTITIES, TENANT, get, ld_notify


def speeds(client, values_at: list[tuple[float, str]]) -> None:
    for value, at in values_at:
        ld_notify(
            client, [{"id": B9211, "type": "Vehicle", "speed": {"type": "Property", "value": value, "observedAt": at}}]
        )


def v2_speed(notify, client, value: float, at: str) -> None:
    """An NGSIv2 sample: no observedAt, its time is the row time."""
    entity = {
        "id": B9211,
        "type": "Vehicle",
        "speed": {"type": "Number", "value": value},
        "TimeInstant": {"type": "DateTime", "value": at},
    }
    notify(client, {"subscriptionId": "s", "data": [entity]}, {"Fiware-Service": TENANT})


def aggregated(client, methods: str, **params) -> dict:
    return get(
        client,
        path=f"{ENTITIES}/{B9211}",
        params={"format": "aggregatedValues", "aggrMethods": methods, "attrs": "speed", **params},
    ).json()["speed"]


def test_periods_start_at_the_first_instance_before_the_end(client):
    speeds(client, [(1, "2024-01-01T00:10:00Z"), (3, "2024-01-01T00:50:00Z"), (5, "2024-01-01T02:20:00Z")])
    before = aggregated(client, "max", aggrPeriodDuration="PT1H", timerel="before", timeAt="2024-01-01T02:00:00Z")
    assert before["max"] == [[3, "2024-01-01T00:10:00Z", "2024-01-01T01:10:00Z"]]
    later = aggregated(client, "max", aggrPeriodDuration="PT1H", timerel="before", timeAt="2024-01-01T00:30:00Z")
    assert later["max"] == [[1, "2024-01-01T00:10:00Z", "2024-01-01T01:10:00Z"]]


def test_an_instance_without_observed_at_can_be_the_first(client, notify):
    """The first instance is an NGSIv2 sample (row time only): periods start there."""
    v2_speed(notify, client, 2, "2024-01-01T00:05:00Z")
    speeds(client, [(4, "2024-01-01T00:40:00Z"), (6, "2024-01-01T01:30:00Z")])
    got = aggregated(client, "totalCount,max", aggrPeriodDuration="PT1H")
    values = got if isinstance(got, list) else [got]
    starts = {period[1] for series in values for period in series["totalCount"]}
    assert min(starts) == "2024-01-01T00:05:00Z"
    assert sorted(starts) == ["2024-01-01T00:05:00Z", "2024-01-01T01:05:00Z"]
    assert sum(period[0] for series in values for period in series["totalCount"]) == 3


@pytest.mark.parametrize(
    ("first", "last"),
    [
        ("1901-12-31T23:59:59.999999Z", "1902-01-01T00:00:00.000001Z"),
        ("1999-12-31T23:59:59.999999Z", "2000-01-01T00:00:00.000001Z"),
        ("2037-12-31T23:59:59.999999Z", "2038-01-01T00:00:00.000001Z"),
        ("2106-02-07T06:28:15.999999Z", "2999-12-31T23:59:59.999999Z"),
    ],
)
def test_instance_times_are_exact_to_the_microsecond(client, first, last):
    speeds(client, [(1, first), (2, last)])
    whole = aggregated(client, "max", aggrPeriodDuration="PT0S")
    assert whole["max"] == [[2, first, last]]
    hourly = aggregated(client, "totalCount", aggrPeriodDuration="PT1H")
    assert hourly["totalCount"][0][1] == first
    retrieved = get(client, path=f"{ENTITIES}/{B9211}", params={"attrs": "speed"}).json()["speed"]
    assert sorted(instance["observedAt"] for instance in retrieved) == [first, last]
