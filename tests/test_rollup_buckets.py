"""The bucket query's rollup part (``storage.rollup_reads.bucket_part``) gives
what the raw samples give: for random data (late and out of order, several
samples at one instant, ties of values, integers and floats, texts), every
width a level serves, and windows of whole minutes and hours, each row
(count, sum, integers, minimum and maximum with the time of the earliest
sample holding it, first and last) equals one computed in Python from the
raw samples; merged and hot rows alike, also after deletes. The whole
bucket query (``storage.sql.buckets.bucket_sql``: rollups for the window's
whole hours and minutes, raw samples for its edges) equals the raw samples'
buckets over random windows cutting minutes anywhere.

Numbers are multiples of 1/8: every sum is exact in any order."""

from __future__ import annotations

import random
from datetime import UTC, datetime, timedelta

import pytest

from tsdb_service.core.buckets import LADDER
from tsdb_service.core.config import Settings
from tsdb_service.core.model import AttrSample, EntitySample, Kind
from tsdb_service.core.query import TimeRange
from tsdb_service.read.buckets import BucketRead
from tsdb_service.storage import open_store
from tsdb_service.storage.rollup_reads import Piece, bucket_levels, bucket_part, split_window
from tsdb_service.storage.sql.buckets import BUCKET_COLUMNS, as_buckets, raw_part
from tsdb_service.write.ops import AppendSamples, DeleteSamples

T0 = datetime(2024, 5, 1, 21, tzinfo=UTC)
US = timedelta(microseconds=1)
EPOCH = datetime(1970, 1, 1, tzinfo=UTC)
WIDTHS = [w for w in LADDER if bucket_levels(w)]


def micros(moment: datetime) -> int:
    return (moment - EPOCH) // US


def samples(rng: random.Random, n: int) -> list[EntitySample]:
    out, times = [], []
    for _ in range(n):
        at = T0 + timedelta(microseconds=rng.randrange(9 * 3600 * 10**6))
        if times and rng.random() < 0.1:
            at = rng.choice(times)
        times.append(at)
        pick = rng.random()
        if pick < 0.1:
            attr = AttrSample("v", "Text", Kind.TEXT, txt="on")
        elif pick < 0.45:
            attr = AttrSample("v", "Integer", Kind.INTEGER, num=float(rng.randrange(-5, 5)))
        else:
            attr = AttrSample("v", "Number", Kind.NUMBER, num=rng.randrange(-40, 40) / 8)
        out.append(EntitySample("", "/", rng.choice("ab"), "T", at, [attr]))
    return out


def reference(store, width: timedelta, start: datetime, end: datetime) -> list[tuple]:
    """BucketRow tuples from the raw samples in [start, end)."""
    q = store.querier()
    rows = q._fetch("SELECT sid, rid, t, kind, num FROM samples_all", [])
    w = width // US
    cells: dict[tuple, list] = {}
    for sid, rid, t, kind, num in rows:
        tu = micros(t.replace(tzinfo=UTC))
        if kind not in (Kind.NUMBER, Kind.INTEGER) or num is None or not micros(start) <= tu < micros(end):
            continue
        cells.setdefault((sid, tu - tu % w), []).append((tu, rid, num, kind == Kind.INTEGER))
    out = []
    for (sid, bucket), held in sorted(cells.items()):
        low, high = min(h[2] for h in held), max(h[2] for h in held)
        first, last = min(held, key=lambda h: (h[0], h[1])), max(held, key=lambda h: (h[0], h[1]))
        out.append(
            (
                sid,
                bucket,
                len(held),
                float(sum(h[2] for h in held)),
                all(h[3] for h in held),
                low,
                min(h[0] for h in held if h[2] == low),
                high,
                min(h[0] for h in held if h[2] == high),
                first[2],
                first[0],
                last[2],
                last[0],
            )
        )
    return out


def from_rollups(store, width: timedelta, start: datetime, end: datetime) -> list[tuple]:
    q = store.querier()
    sids = [r[0] for r in q._fetch("SELECT sid FROM series ORDER BY sid", [])]
    [piece] = [p for p in split_window(TimeRange(start, end - US), bucket_levels(width)) if p.level is not None][:1]
    assert (piece.start, piece.end) == (start, end)  # the window is whole buckets of the coarsest level
    sql, params = bucket_part(q.dialect, piece.level, sids, Piece(piece.level, start, end), width)
    return sorted(tuple(r) for r in q._fetch(sql, params))


@pytest.fixture
def store(store_url):
    s = open_store(Settings(db=store_url))
    yield s
    s.close()


def test_rollup_buckets_equal_raw_buckets(store):
    rng = random.Random(38)
    store.write_sync([AppendSamples(samples(rng, 500), dedup=False)])
    store.write_sync([AppendSamples(samples(rng, 200), dedup=False)])  # late, into the same buckets
    for round_ in range(3):
        if round_ == 1:
            store.compact()  # merged rows answer as hot ones do
        if round_ == 2:
            sids = tuple(r[0] for r in store.querier()._fetch("SELECT sid FROM series", []))
            store.write_sync(
                [DeleteSamples(sids, T0 + timedelta(hours=2, minutes=7), T0 + timedelta(hours=4, seconds=5))]
            )
        for width in WIDTHS:
            level = bucket_levels(width)[0]
            for _ in range(2):
                span = max(width, level.width) * rng.randrange(1, 6)
                start = T0 - timedelta(hours=1) + level.width * rng.randrange(int(timedelta(hours=10) / level.width))
                start -= (start - EPOCH) % width if rng.random() < 0.5 else timedelta(0)
                start -= (start - EPOCH) % level.width
                end = start + span
                assert from_rollups(store, width, start, end) == reference(store, width, start, end), (width, start)


def raw_buckets(q, sids: list[int], ask: BucketRead) -> list:
    """The bucket query's rows as raw samples alone give them."""
    sql, params = raw_part(q.dialect, sids, ask.time, ask.width, (), ask.extreme_times)
    return as_buckets(q._fetch(f"SELECT {BUCKET_COLUMNS} FROM ({sql}) AS b ORDER BY sid, start", params))


def test_the_bucket_query_equals_raw_over_random_windows(store):
    rng = random.Random(3838)
    store.write_sync([AppendSamples(samples(rng, 400), dedup=False)])
    store.compact()  # merged rows, and hot ones from the late samples below
    store.write_sync([AppendSamples(samples(rng, 200), dedup=False)])
    q = store.querier()
    sids = [r[0] for r in q._fetch("SELECT sid FROM series ORDER BY sid", [])]
    cut = T0 + timedelta(hours=3, minutes=10, seconds=17)
    store.write_sync([DeleteSamples(tuple(sids), cut, cut + timedelta(hours=1, minutes=33))])
    for _ in range(16):
        width = rng.choice(WIDTHS)
        start = T0 - timedelta(minutes=20) + timedelta(microseconds=rng.randrange(9 * 3600 * 10**6))
        end = start + timedelta(microseconds=rng.randrange(60 * 10**6, 6 * 3600 * 10**6))
        ask = BucketRead(tuple(sids), TimeRange(start, end), width, (), rng.random() < 0.5)
        assert q.buckets(ask) == raw_buckets(q, sids, ask), (width, start, end)
