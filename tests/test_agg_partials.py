"""Hourly aggregate partials in memory (storage/partials.py) give exactly the
answer of the grouped SQL: random data, many windows, periods and methods,
after commits that follow the caching, after every kind of delete, under the
memory bound, and while a load races the writer.

Both backends keep them: DuckDB's writer publishes its commits and its
deletes drop series; PostgreSQL's querier checks each series' change count
in the database (migration 0011) before using its partials, so the same
tests hold there (and ``test_pg_series_changes`` pins what other sessions
and replicas write).

Numbers are multiples of 1/8: every sum is exact in any order, so the
SQL's sums (in scan order) and the partials' (exact) must be equal, bit for
bit. ``test_sums_are_exact`` pins what happens when they are not."""

from __future__ import annotations

import math
import random
from datetime import UTC, datetime, timedelta

import pytest

from tsdb_service.core.config import Settings
from tsdb_service.core.model import AttrSample, EntitySample, Kind
from tsdb_service.core.query import AggBranch, Aggregation, AggrMethod, AggrPeriod, EntityFilter, Scope, TimeRange
from tsdb_service.read.requests import AggregateRead, InstancesRead, SeriesSelect
from tsdb_service.storage import open_store
from tsdb_service.storage.partials import HourlyPartials, exact_parts
from tsdb_service.write.ops import AppendSamples, DeleteInstance, DeleteSamples, ReplaceInstance

T0 = datetime(2024, 5, 1, 22, tzinfo=UTC)  # a day and a month boundary inside the data
SCOPE = Scope("", ("/",))
HOUR = timedelta(hours=1)
PERIODS = (AggrPeriod.HOUR, AggrPeriod.DAY, AggrPeriod.MONTH, AggrPeriod.YEAR, None)


@pytest.fixture
def store(store_url):
    s = open_store(Settings(db=store_url, retention="*=3650d", retention_pause=0))
    yield s
    s.close()


def cached(store, seed: int, samples: int, rounds: int) -> random.Random:
    """Random samples written and aggregated (so cached) ``rounds`` times,
    checked against SQL; the generator, to go on with."""
    rng = random.Random(seed)
    with_partials(store)
    store.write_sync([AppendSamples(random_samples(rng, samples))])
    assert_all_same(store, rng, rounds)
    return rng


def with_partials(store, max_hours: int = 100_000) -> HourlyPartials:
    """The querier's partials, bounded to ``max_hours``."""
    partials = store.querier()._partials()
    assert partials is not None
    partials.max_hours = max_hours
    return partials


def sample(eid: str, at: datetime, value: float | None, kind: Kind = Kind.NUMBER) -> EntitySample:
    if kind is Kind.TEXT:
        attr = AttrSample("v", "Text", Kind.TEXT, txt="x")
    elif kind is Kind.NULL:
        attr = AttrSample("v", None, Kind.NULL)
    else:
        attr = AttrSample("v", "Number", kind, num=value)
    return EntitySample("", "/", eid, "T", at, [attr])


def random_samples(rng: random.Random, n: int, span_hours: int = 30) -> list[EntitySample]:
    out = []
    for _ in range(n):
        at = T0 + timedelta(microseconds=rng.randrange(span_hours * 3600 * 10**6))
        pick = rng.random()
        if pick < 0.1:
            out.append(sample(rng.choice("ab"), at, None, Kind.TEXT if pick < 0.05 else Kind.NULL))
        elif pick < 0.4:
            out.append(sample(rng.choice("abc"), at, float(rng.randrange(-50, 50)), Kind.INTEGER))
        else:
            out.append(sample(rng.choice("abc"), at, rng.randrange(-8000, 8000) / 8))
    return out


def sids(store) -> tuple[int, ...]:
    return tuple(sorted(r.sid for r in store.querier().series(SeriesSelect(SCOPE, EntityFilter(types=("T",))))))


def windows(rng: random.Random, n: int) -> list[TimeRange]:
    """Open, hour-aligned, millisecond and microsecond bounds, some empty."""
    out = [TimeRange(), TimeRange(T0 + 2 * HOUR, None), TimeRange(None, T0 + 5 * HOUR - timedelta(milliseconds=1))]
    for _ in range(n):
        a = T0 + timedelta(microseconds=rng.randrange(-2 * 3600 * 10**6, 32 * 3600 * 10**6))
        b = a + timedelta(microseconds=rng.randrange(0, 20 * 3600 * 10**6))
        if rng.random() < 0.3:
            a = a.replace(minute=0, second=0, microsecond=0)
        if rng.random() < 0.3:
            b = b.replace(microsecond=(b.microsecond // 1000) * 1000)
        out.append(TimeRange(a if rng.random() < 0.9 else None, b if rng.random() < 0.9 else None))
    return out


def assert_same(store, time: TimeRange, agg: Aggregation) -> None:
    q = store.querier()
    branches = [AggBranch(sids(store))]
    got = sorted(q.aggregate(AggregateRead(branches, time, agg)))
    want = sorted(q._aggregate_sql(branches, time, agg))
    assert got == want, (time, agg)


def assert_all_same(store, rng: random.Random, n_windows: int = 12) -> None:
    for time in windows(rng, n_windows):
        for period in PERIODS:
            for method in AggrMethod:
                assert_same(store, time, Aggregation(method, period))


def test_partials_answer_as_sql_does(store):
    rng = random.Random(15)
    partials = with_partials(store)
    store.write_sync([AppendSamples(random_samples(rng, 600))])
    assert_all_same(store, rng)
    assert partials.hits > 0 and partials.hours > 0


def test_commits_after_caching_are_counted(store):
    rng = cached(store, 16, 300, 4)  # every series cached from before T0 on
    for _ in range(3):
        # New hours, late samples into cached hours, new series.
        more = [*random_samples(rng, 80, span_hours=40), sample("d", T0 + 3 * HOUR, 1.5)]
        store.write_sync([AppendSamples(more)])
        assert_all_same(store, rng, 4)


def test_deletes_drop_what_they_touch(store):
    rng = cached(store, 17, 300, 3)
    all_sids = sids(store)
    store.write_sync([DeleteSamples(all_sids[:1], T0 + 3 * HOUR, T0 + 7 * HOUR + timedelta(minutes=20))])
    assert_all_same(store, rng, 3)
    store.write_sync([DeleteSamples(all_sids[1:2])])
    assert_all_same(store, rng, 3)


def test_instance_deletes_and_replacements_drop_the_series(store):
    rng = cached(store, 18, 200, 2)
    q = store.querier()
    rows = [r for r in q.temporal_instances(InstancesRead(sids(store))) if r.kind == int(Kind.NUMBER)]
    replaced, deleted = rows[0], rows[1]
    new = AttrSample("v", "Number", Kind.NUMBER, num=1e3)
    store.write_sync([ReplaceInstance(replaced.sid, replaced.iid, new, datetime.now(UTC))])
    assert_all_same(store, rng, 2)
    store.write_sync([DeleteInstance(deleted.sid, deleted.iid)])
    assert_all_same(store, rng, 2)


def test_retention_drops_what_it_deletes(store):
    with_partials(store)
    old = [sample("a", datetime.now(UTC) - timedelta(days=4000, minutes=i), float(i)) for i in range(30)]
    store.write_sync([AppendSamples([*old, *random_samples(random.Random(19), 100)])])
    everything = Aggregation(AggrMethod.SUM, AggrPeriod.YEAR)
    assert_same(store, TimeRange(), everything)
    assert store.retention.run_once()
    assert_same(store, TimeRange(), everything)


def test_memory_stays_within_the_bound(store):
    rng = random.Random(20)
    partials = with_partials(store, max_hours=25)
    store.write_sync([AppendSamples(random_samples(rng, 400))])  # ~90 series-hours
    for time in windows(rng, 6):
        assert_same(store, time, Aggregation(AggrMethod.AVG, AggrPeriod.HOUR))
        assert partials.hours <= 25
    store.write_sync([AppendSamples(random_samples(rng, 100, span_hours=60))])
    assert partials.hours <= 25
    assert_same(store, TimeRange(), Aggregation(AggrMethod.SUM, AggrPeriod.DAY))


@pytest.mark.parametrize("seen", [True, False], ids=["commit-seen-by-load", "commit-after-load"])
def test_a_commit_racing_the_load_counts_once(store, seen):
    """A commit published while a load runs: counted once whether the load's
    snapshot saw it (committed before the query) or not (after it)."""
    store.write_sync([AppendSamples([sample("a", T0 + timedelta(minutes=i), float(i)) for i in range(10)])])
    with_partials(store)
    q = store.querier()
    real_load = q._load_partials
    late = [sample("a", T0 + timedelta(minutes=30), 100.0)]

    def racing_load(load_sids, lo):
        if seen:
            store.write_sync([AppendSamples(late)])
            return real_load(load_sids, lo)
        rows = real_load(load_sids, lo)
        store.write_sync([AppendSamples(late)])
        return rows

    q._load_partials = racing_load
    agg = Aggregation(AggrMethod.SUM, AggrPeriod.HOUR)
    q.aggregate(AggregateRead([AggBranch(sids(store))], TimeRange(), agg))
    q._load_partials = real_load
    assert_same(store, TimeRange(), agg)
    (row,) = q.aggregate(AggregateRead([AggBranch(sids(store))], TimeRange(), agg))
    assert (row.n_numeric, row.value) == (11, 145.0)


def test_sums_are_exact(store):
    """Where SQL's running sum rounds, the partials give the correctly
    rounded sum of the numbers (``math.fsum``), however hours combine and
    samples arrive."""
    rng = random.Random(21)
    with_partials(store)
    numbers = [rng.uniform(-1, 1) * 10 ** rng.randrange(-3, 17) for _ in range(200)]
    times = [T0 + timedelta(seconds=rng.randrange(40 * 3600)) for _ in numbers]
    first = [sample("a", t, v) for t, v in zip(times[:120], numbers[:120], strict=True)]
    store.write_sync([AppendSamples(first)])
    q = store.querier()
    branches = [AggBranch(sids(store))]
    q.aggregate(
        AggregateRead(branches, TimeRange(), Aggregation(AggrMethod.SUM, None))
    )  # the rest arrives after the load
    store.write_sync([AppendSamples([sample("a", t, v) for t, v in zip(times[120:], numbers[120:], strict=True)])])
    (row,) = q.aggregate(AggregateRead(branches, TimeRange(), Aggregation(AggrMethod.SUM, None)))
    assert row.value == math.fsum(numbers)
    by_day: dict[str, list[float]] = {}
    for t, v in zip(times, numbers, strict=True):
        by_day.setdefault(t.strftime("%Y-%m-%dT00:00:00.000+00:00"), []).append(v)
    rows = q.aggregate(AggregateRead(branches, TimeRange(), Aggregation(AggrMethod.SUM, AggrPeriod.DAY)))
    assert {r.bucket: r.value for r in rows} == {day: math.fsum(vs) for day, vs in by_day.items()}


def test_exact_parts_keep_the_exact_sum():
    rng = random.Random(22)
    for _ in range(200):
        values = [rng.uniform(-1, 1) * 10 ** rng.randrange(-300, 300) for _ in range(rng.randrange(0, 40))]
        parts = exact_parts(values)
        assert math.fsum(parts) == math.fsum(values)
        assert math.fsum([*parts, *(-v for v in values)]) == 0.0
    assert exact_parts([1e16, 1.0, -1e16, 1.0]) == [2.0]
    assert exact_parts([1e300, 1e-300]) == [1e300, 1e-300]


def test_a_load_too_big_is_left_to_sql(store, monkeypatch):
    """Loading brings each hour's numbers into memory once: above
    ``MAX_LOAD_SAMPLES`` the window is aggregated by SQL and nothing is kept."""
    rng = random.Random(23)
    partials = with_partials(store)
    store.write_sync([AppendSamples(random_samples(rng, 300))])
    monkeypatch.setattr("tsdb_service.storage.sql.aggregate.MAX_LOAD_SAMPLES", 50)
    assert_same(store, TimeRange(), Aggregation(AggrMethod.AVG, AggrPeriod.DAY))
    assert partials.hours == 0
    for time in windows(rng, 4):  # narrow windows load (and keep) their few samples
        assert_same(store, time, Aggregation(AggrMethod.AVG, AggrPeriod.DAY))
