"""An aggregation over many series: PostgreSQL groups them in parts at
once (``PostgresQuerier._fetch_parts``), and the answer is the one a single
statement gives, on both backends: every entity, every period, periods
from the first instance of any of them."""

from __future__ import annotations

import pytest

from tests.ngsild_fixtures import ENTITIES, get, ld_notify
from tsdb_service.storage.postgres.querier import AGGREGATE_SPLIT_FROM

ROBOTS = AGGREGATE_SPLIT_FROM + 9


def robot(n: int) -> str:
    return f"urn:ngsi-ld:Robot:{n:03d}"


def store_robots(client) -> dict[str, list[tuple[int, str]]]:
    """Robot n reports n, n + 1, n + 2 at minutes 10·n % 50 + 5, +30, +70 (the
    first robot's first instance, at 00:05, is the earliest)."""
    sent: dict[str, list[tuple[int, str]]] = {}
    for n in range(ROBOTS):
        minute = 10 * n % 50 + 5
        for k, offset in enumerate((0, 30, 70)):
            at = minute + offset
            stamp = f"2024-01-01T{at // 60:02d}:{at % 60:02d}:00Z"
            ld_notify(
                client,
                [{"id": robot(n), "type": "Robot", "load": {"type": "Property", "value": n + k, "observedAt": stamp}}],
            )
            sent.setdefault(robot(n), []).append((n + k, stamp))
    return sent


def hourly(values: list[tuple[int, str]]) -> list[tuple[str, str, list[int]]]:
    """(start, end, values) of the hourly periods from 00:05 (the first
    instance of all robots) that hold values."""
    periods: dict[int, list[int]] = {}
    for value, stamp in values:
        minutes = int(stamp[11:13]) * 60 + int(stamp[14:16])
        periods.setdefault((minutes - 5) // 60, []).append(value)

    def text(minutes: int) -> str:
        return f"2024-01-01T{minutes // 60:02d}:{minutes % 60:02d}:00Z"

    return [(text(5 + 60 * k), text(65 + 60 * k), periods[k]) for k in sorted(periods)]


def hourly_robots(client, methods: str) -> list[dict]:
    params = {"type": "Robot", "attrs": "load", "format": "aggregatedValues", "aggrMethods": methods}
    return get(client, path=ENTITIES, params={**params, "aggrPeriodDuration": "PT1H", "limit": "100"}).json()


def test_many_series_aggregate_as_one(client, backend):
    sent = store_robots(client)
    querier = client.app.state.store.querier()
    fetch = querier._fetch
    statements: list[str] = []

    def counting(sql, params, *args, **kwargs):
        statements.append(sql)
        return fetch(sql, params, *args, **kwargs)

    querier._fetch = counting
    try:
        body = hourly_robots(client, "max,totalCount")
    finally:
        del querier._fetch
    assert sorted(entity["id"] for entity in body) == sorted(sent)
    for entity in body:
        periods = hourly(sent[entity["id"]])
        assert entity["load"]["max"] == [[max(vs), lo, hi] for lo, hi, vs in periods], entity["id"]
        assert entity["load"]["totalCount"] == [[len(vs), lo, hi] for lo, hi, vs in periods], entity["id"]
    grouped = [sql for sql in statements if "GROUP BY" in sql]
    assert len(grouped) == (2 if backend == "postgresql" else 1), grouped


class _Deferred:
    """A helper pool whose work runs when its result is asked for: the
    parts of one aggregation then run one after the other."""

    def submit(self, fn, *args, **kwargs):
        return _Later(lambda: fn(*args, **kwargs))


class _Later:
    def __init__(self, work):
        self.work = work

    def result(self):
        return self.work()


def test_a_write_between_the_parts(client, backend, monkeypatch):
    """PostgreSQL's parts see two snapshots: an instance older than every
    other, stored between them, moves the second part's origin; the
    answer must still be the one of a single statement (periods from that
    instance), not two grids."""
    if backend != "postgresql":
        pytest.skip("only PostgreSQL groups in parts")
    sent = store_robots(client)
    querier = client.app.state.store.querier()
    monkeypatch.setattr(querier, "_helpers", _Deferred())
    fetch = querier._fetch
    grouped: list[str] = []
    last = robot(ROBOTS - 1)  # in the second part

    def write_after_first_part(sql, params, *args, **kwargs):
        rows = fetch(sql, params, *args, **kwargs)
        if "GROUP BY" in sql:
            grouped.append(sql)
            if len(grouped) == 1:  # 00:02, not on the hourly grid from 00:05
                ld_notify(
                    client,
                    [
                        {
                            "id": last,
                            "type": "Robot",
                            "load": {"type": "Property", "value": 99, "observedAt": "2024-01-01T00:02:00Z"},
                        }
                    ],
                )
        return rows

    monkeypatch.setattr(querier, "_fetch", write_after_first_part)
    body = hourly_robots(client, "max")
    assert len(grouped) == 3, grouped  # two parts, then the one statement
    starts = {period[1] for entity in body for period in entity["load"]["max"]}
    assert min(starts) == "2024-01-01T00:02:00Z"
    assert all(start[14:16] == "02" for start in starts), sorted(starts)
    assert len(body) == len(sent)
