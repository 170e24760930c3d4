"""The long-window reads (``read.buckets``) on both backends equal the plain
Python reference (``read.memory``) on random data: late and out-of-order
samples, equal times in a series, equal values, nulls, value paths; random
windows whose ends cut buckets. The SQL parts combine exactly: a window
answered as two raw parts and merged (``storage.sql.buckets.combine``, what
rollups plug into) equals the window answered at once.
"""

from __future__ import annotations

import itertools
import random
from datetime import timedelta

import pytest

from tests.support import long_windows as data
from tsdb_service.core.buckets import LADDER, bucket_start
from tsdb_service.core.query import EntityFilter, Scope, TimeRange
from tsdb_service.read.buckets import BucketRead, ChangesRead
from tsdb_service.read.memory import MemoryQuerier, MemorySample
from tsdb_service.read.requests import SamplesIn, SeriesSelect
from tsdb_service.storage.sql.buckets import BUCKET_COLUMNS, combine, raw_part

COLUMNS = (
    "rid, sid, iid, t, kind, atype, num, txt, js, geo, lon, lat, min_lon, min_lat, max_lon, max_lat, md, "
    "observed_at, created_at, modified_at, deleted_at"
)
WIDTHS = [w for w in LADDER if timedelta(seconds=10) <= w <= timedelta(days=1)]


@pytest.fixture(scope="module")
def pair(client_factory, store_url_factory):
    with client_factory(store_url_factory("bucket_reads")) as client:
        data.load(client)
        q = client.app.state.store.querier()
        memory = MemoryQuerier()
        for ref in q.series(SeriesSelect(Scope(data.TENANT), EntityFilter())):
            memory.add_series(data.TENANT, ref)
        rows = q._fetch(f"SELECT {COLUMNS} FROM {q.dialect.samples(COLUMNS)}", [])
        memory.add_samples(MemorySample(*row) for row in rows)
        yield q, memory


def _sids(q, attr: str) -> list[int]:
    return [r.sid for r in q.series(SeriesSelect(Scope(data.TENANT), EntityFilter(), {attr}))]


def _window(rng: random.Random) -> TimeRange:
    start = data.T0 - timedelta(minutes=30) + timedelta(milliseconds=rng.randrange(4 * 3_600_000))
    return TimeRange(start, start + timedelta(milliseconds=rng.randrange(600_000, 4 * 3_600_000)))


def _same_buckets(got, want):
    assert [(r.sid, r.start) for r in got] == [(r.sid, r.start) for r in want]
    for a, b in zip(got, want, strict=True):
        assert a._replace(total=0.0) == b._replace(total=0.0)
        assert a.total == pytest.approx(b.total, abs=1e-9)


@pytest.mark.parametrize("seed", range(8))
@pytest.mark.parametrize(("attr", "steps"), [("speed", ()), ("count", ()), ("odom", ("v",)), ("mode", ())])
def test_buckets_equal_the_reference(pair, seed, attr, steps):
    backend, memory = pair
    rng = random.Random(seed)
    ask = BucketRead(_sids(backend, attr), _window(rng), rng.choice(WIDTHS), steps, extreme_times=seed % 2 == 0)
    want = memory.buckets(ask)
    _same_buckets(backend.buckets(ask), want)
    if attr == "mode":
        assert want == []  # texts are no numbers: drawn from their changes
    else:
        assert bool(want) == (memory.span(SamplesIn(ask.sids, ask.time)) is not None)
    for row in want:
        assert row.start == bucket_start(_utc(row.start), ask.width).timestamp() * 1_000_000
        if ask.extreme_times:
            assert row.first_t <= row.min_t <= row.last_t and row.first_t <= row.max_t <= row.last_t
        else:
            assert row.min_t is None and row.max_t is None


def _utc(micros: int):
    return data.T0 + timedelta(microseconds=micros - int(data.T0.timestamp() * 1_000_000))


def test_the_whole_store_and_the_ties(pair):
    """Every bucket of every series over all the data: equal values and
    equal times in one bucket go to the earliest sample, then the lowest row
    id (the latest for ``last``) on every backend."""
    backend, memory = pair
    for attr, steps in (("speed", ()), ("count", ()), ("odom", ("v",))):
        for width in (timedelta(minutes=1), timedelta(hours=1), timedelta(days=1)):
            ask = BucketRead(_sids(backend, attr), TimeRange(None, None), width, steps)
            _same_buckets(backend.buckets(ask), memory.buckets(ask))


@pytest.mark.parametrize("seed", range(6))
def test_two_parts_combined_equal_one(pair, seed):
    """What rollups will rely on: a window cut in two parts (any instant)
    answered by ``combine`` gives the rows of the window answered at once."""
    backend, _ = pair
    rng = random.Random(seed)
    window = _window(rng)
    width = rng.choice(WIDTHS)
    cut = window.start + (window.end - window.start) * rng.random()
    cut = cut.replace(microsecond=cut.microsecond // 1000 * 1000)
    before = TimeRange(window.start, cut - timedelta(microseconds=1))
    sids = _sids(backend, "count")
    d = backend.dialect
    parts = [raw_part(d, sids, before, width), raw_part(d, sids, TimeRange(cut, window.end), width)]
    sql, params = combine(d, parts)
    merged = backend._fetch(f"SELECT {BUCKET_COLUMNS} FROM ({sql}) AS b ORDER BY sid, start", params)
    whole = backend.buckets(BucketRead(sids, window, width))
    assert [tuple(r) for r in whole] == [tuple(r) for r in merged]


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize(("attr", "steps"), [("mode", ()), ("busy", ()), ("count", ()), ("odom", ("s",))])
@pytest.mark.parametrize("limit", [3, 40, 100_000])
def test_state_changes_equal_the_reference(pair, seed, attr, steps, limit):
    backend, memory = pair
    ask = ChangesRead(_sids(backend, attr), _window(random.Random(seed)), limit, steps)
    want = memory.state_changes(ask)
    assert backend.state_changes(ask) == want
    every = memory.state_changes(ChangesRead(ask.sids, ask.time, 10**9, steps)).changes
    assert want.changes == every[-limit:], "the newest are kept"
    assert want.truncated == (len(every) > limit)


def test_changes_keep_transitions_only(pair):
    backend, _ = pair
    page = backend.state_changes(ChangesRead(_sids(backend, "busy"), TimeRange(None, None), 100_000))
    assert not page.truncated
    by_sid: dict[int, list] = {}
    for change in page.changes:
        by_sid.setdefault(change.sid, []).append(change.num)
    for values in by_sid.values():
        assert all(a != b for a, b in itertools.pairwise(values)), "consecutive changes differ"


def test_span(pair):
    backend, memory = pair
    for attr in ("speed", "mode"):
        for window in (TimeRange(None, None), TimeRange(data.T0 + timedelta(hours=1), None)):
            ask = SamplesIn(_sids(backend, attr), window)
            assert backend.span(ask) == memory.span(ask) is not None
    assert backend.span(SamplesIn(_sids(backend, "speed"), TimeRange(*data.OUTAGE))) is None


@pytest.mark.parametrize("most", [0, 1, 50, 10**6])
def test_counting_up_to_and_reading_samples(pair, most):
    """``count_up_to`` stops at ``most``; ``samples`` gives the first ``most``
    by series, time and row id, times in epoch µs."""
    backend, memory = pair
    sids = _sids(backend, "mode") + _sids(backend, "speed")
    for window in (TimeRange(None, None), TimeRange(data.T0 + timedelta(hours=1), data.T0 + timedelta(hours=2))):
        ask = SamplesIn(sids, window)
        assert backend.count_up_to(ask, most) == memory.count_up_to(ask, most) == min(most, memory.count(ask))
        got = [tuple(row) for row in backend.samples(ask, most)]
        assert got == [tuple(row) for row in memory.samples(ask, most)]
        assert len(got) == min(most, memory.count(ask))
