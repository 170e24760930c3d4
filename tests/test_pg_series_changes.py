"""PostgreSQL keeps hourly partials in memory (storage.partials) although
other sessions write the same database: before using a series' partials the
querier reads its change count from ``series_changes`` (migration 0011),
which triggers on ``samples`` move in every writing transaction.

Pinned here: what another replica, plain SQL (insert, update, delete) and a
TRUNCATE change is seen by the next aggregation; an unchanged series is
answered without loading; a rolled-back write counts nothing; and the rows
of ended sessions fold into one per series without changing any sum.
"""

from __future__ import annotations

import time
from datetime import UTC, datetime, timedelta

import psycopg
import pytest

from tsdb_service.core.config import Settings
from tsdb_service.core.model import AttrSample, EntitySample, Kind
from tsdb_service.core.query import AggBranch, Aggregation, AggrMethod, AggrPeriod, EntityFilter, Scope, TimeRange
from tsdb_service.read.requests import AggregateRead, SeriesSelect
from tsdb_service.storage import open_store
from tsdb_service.storage.rollup_repair import rebuild
from tsdb_service.write.ops import AppendSamples

T0 = datetime(2024, 5, 1, 10, tzinfo=UTC)
SCOPE = Scope("", ("/",))
HOURLY_SUM = Aggregation(AggrMethod.SUM, AggrPeriod.HOUR)


@pytest.fixture
def url(store_url, backend) -> str:
    if backend != "postgresql":
        pytest.skip("PostgreSQL only: DuckDB has one writer, which publishes its commits")
    return store_url


@pytest.fixture
def store(url):
    s = open_store(Settings(db=url))
    yield s
    s.close()


def samples(eid: str, values: list[float], start: datetime = T0) -> list[EntitySample]:
    return [
        EntitySample(
            "", "/", eid, "T", start + timedelta(minutes=7 * i), [AttrSample("v", "Number", Kind.NUMBER, num=v)]
        )
        for i, v in enumerate(values)
    ]


def hourly(store) -> dict[tuple[int, str | None], float | None]:
    """The hourly sums from the querier (partials where it may use them),
    checked equal to SQL's."""
    q = store.querier()
    refs = q.series(SeriesSelect(SCOPE, EntityFilter(types=("T",))))
    branches = [AggBranch(tuple(sorted(r.sid for r in refs)))]
    got = sorted(q.aggregate(AggregateRead(branches, TimeRange(), HOURLY_SUM)))
    assert got == sorted(q._aggregate_sql(branches, TimeRange(), HOURLY_SUM))
    return {(row.sid, row.bucket): row.value for row in got}


def series_ids(store) -> list[int]:
    return sorted(r.sid for r in store.querier().series(SeriesSelect(SCOPE, EntityFilter(types=("T",)))))


def total(store) -> float:
    return sum(v or 0 for v in hourly(store).values())


def counts(url: str) -> dict[int, int]:
    with psycopg.connect(url) as conn:
        return dict(conn.execute("SELECT block, sum(n)::bigint FROM series_changes GROUP BY block").fetchall())


def gone(url: str, timeout_s: float = 10.0) -> None:
    """Wait until the closed stores' sessions have ended on the server (a
    backend exits a moment after its client disconnects)."""
    deadline = time.monotonic() + timeout_s
    with psycopg.connect(url, autocommit=True) as conn:
        while time.monotonic() < deadline:
            alive = conn.execute(
                "SELECT count(*) FROM series_changes WHERE pid IN (SELECT pid FROM pg_stat_activity)"
            ).fetchone()
            if alive == (0,):
                return
            time.sleep(0.05)
    raise AssertionError("the closed stores' sessions did not end")


def test_an_unchanged_series_is_answered_from_memory(store):
    store.write_sync([AppendSamples(samples("a", [1, 2, 3, 4, 5, 6, 7, 8, 9, 10]))])
    partials = store.querier()._partials()
    assert total(store) == 55
    misses = partials.misses
    for _ in range(3):
        assert total(store) == 55
    assert partials.misses == misses and partials.hits >= 3
    store.write_sync([AppendSamples(samples("a", [100], T0 + timedelta(hours=3)))])
    assert total(store) == 155
    assert partials.misses == misses + 1


def test_another_replica_s_writes_are_seen(store, url):
    store.write_sync([AppendSamples(samples("a", [1, 2, 3]) + samples("b", [10]))])
    assert total(store) == 16
    other = open_store(Settings(db=url))
    try:
        other.write_sync([AppendSamples(samples("a", [1000], T0 + timedelta(minutes=1)))])
        assert total(store) == 1016
    finally:
        other.close()


def test_plain_sql_inserts_updates_and_deletes_are_seen(store, url):
    """(Rollups see inserts by hand through their trigger, not updates and
    deletes: ``rollups rebuild`` does, as the SQL answers compared here read
    them.)"""
    store.write_sync([AppendSamples(samples("a", [1, 2, 3, 4]))])
    assert total(store) == 10
    with psycopg.connect(url, autocommit=True) as conn:
        conn.execute("UPDATE samples SET num = num * 10 WHERE num = 4")
        rebuild(store, series_ids(store))
        assert total(store) == 46
        conn.execute("DELETE FROM samples WHERE num = 1")
        rebuild(store, series_ids(store))
        assert total(store) == 45
        conn.execute(
            "INSERT INTO samples (rid, sid, t, kind, num) "
            "SELECT rid + 1000, sid, t + interval '1 hour', kind, num FROM samples WHERE num = 2"
        )
        assert total(store) == 47
        conn.execute("TRUNCATE samples")
        rebuild(store, series_ids(store))
        assert total(store) == 0


def test_a_rolled_back_write_counts_nothing(store, url):
    store.write_sync([AppendSamples(samples("a", [1, 2]))])
    assert total(store) == 3
    before = counts(url)
    with psycopg.connect(url) as conn:
        conn.execute("DELETE FROM samples")
        conn.rollback()
    assert counts(url) == before
    assert total(store) == 3


def test_ended_sessions_fold_into_one_row_per_series(url):
    for values in ([1, 2], [3], [4, 5, 6]):  # three stores, each its own writer sessions
        s = open_store(Settings(db=url))
        s.write_sync([AppendSamples(samples("a", values, T0 + timedelta(hours=len(values))))])
        s.close()
    gone(url)
    before = counts(url)
    assert before and all(n >= 1 for n in before.values())
    s = open_store(Settings(db=url))  # opening folds the rows of sessions that ended
    try:
        assert counts(url) == before
        with psycopg.connect(url) as conn:
            pids = {row[0] for row in conn.execute("SELECT DISTINCT pid FROM series_changes").fetchall()}
        assert pids == {0}
        assert total(s) == 21
    finally:
        s.close()
