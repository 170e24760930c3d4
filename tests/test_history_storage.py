"""The read/delete seam on a real store: both sample tables, deletes through
the writer, row windows checked against a brute-force model."""

from __future__ import annotations

import random
from datetime import UTC, datetime, timedelta

import pytest

from tsdb_service.core.config import Settings
from tsdb_service.core.model import AttrSample, EntitySample, Kind
from tsdb_service.core.query import EntityFilter, Scope, TimeRange
from tsdb_service.read.requests import RowsRead, SeriesSelect
from tsdb_service.storage import open_store
from tsdb_service.write.ops import AppendSamples, DeleteSamples

T0 = datetime(2024, 5, 1, tzinfo=UTC)
SCOPE = Scope("", ("/",))


@pytest.fixture
def store(store_url):
    s = open_store(Settings(db=store_url))
    yield s
    s.close()


def entity(eid: str, i: int, attrs: dict[str, float], etype: str = "T", tenant: str = "") -> EntitySample:
    return EntitySample(
        tenant,
        "/",
        eid,
        etype,
        T0 + timedelta(seconds=i),
        [AttrSample(a, "Number", Kind.NUMBER, num=v) for a, v in attrs.items()],
    )


def values(store, eid: str, attr: str) -> list[float]:
    q = store.querier()
    sids = [r.sid for r in q.series(SeriesSelect(SCOPE, EntityFilter(ids=(eid,)), {attr}))]
    rows = q.raw_rows(RowsRead(sids, TimeRange(), newest_first=False, limit=10_000, offset=0, one_per_row=True))
    return [row[4] for row in rows]


def test_reads_span_sorted_and_hot_tables(store):
    store.write_sync([AppendSamples([entity("e", i, {"v": float(i)}) for i in range(5)])])
    if hasattr(store, "compact"):
        store.compact(full=False)  # the first five move to the sorted table
    store.write_sync([AppendSamples([entity("e", i, {"v": float(i)}) for i in range(5, 8)])])
    assert values(store, "e", "v") == [float(i) for i in range(8)]


def test_delete_reaches_both_tables(store):
    store.write_sync([AppendSamples([entity("e", i, {"v": float(i)}) for i in range(5)])])
    if hasattr(store, "compact"):
        store.compact(full=True)
    store.write_sync([AppendSamples([entity("e", i, {"v": float(i)}) for i in range(5, 8)])])
    sids = tuple(r.sid for r in store.querier().series(SeriesSelect(SCOPE, EntityFilter(ids=("e",)))))
    store.write_sync([DeleteSamples(sids, T0 + timedelta(seconds=3), T0 + timedelta(seconds=6))])
    assert values(store, "e", "v") == [0.0, 1.0, 2.0, 7.0]
    store.write_sync([DeleteSamples(sids)])
    assert values(store, "e", "v") == []


def test_samples_written_after_a_delete_survive_it(store):
    store.write_sync([AppendSamples([entity("e", i, {"v": float(i)}) for i in range(3)])])
    sids = tuple(r.sid for r in store.querier().series(SeriesSelect(SCOPE, EntityFilter(ids=("e",)))))
    store.write_sync([DeleteSamples(sids)])
    store.write_sync([AppendSamples([entity("e", 1, {"v": 9.0})])])  # same time as a deleted one
    assert values(store, "e", "v") == [9.0]


def test_new_series_are_visible_at_once(store):
    q = store.querier()
    assert q.series(SeriesSelect(SCOPE, EntityFilter(ids=("x",)))) == []
    store.write_sync([AppendSamples([entity("x", 0, {"a": 1.0})])])
    assert [r.attr for r in q.series(SeriesSelect(SCOPE, EntityFilter(ids=("x",))))] == ["a"]
    store.write_sync([AppendSamples([entity("x", 1, {"b": 2.0})])])
    assert sorted(r.attr for r in q.series(SeriesSelect(SCOPE, EntityFilter(ids=("x",))))) == ["a", "b"]


def test_catalog_keeps_tenants_apart(store):
    store.write_sync(
        [AppendSamples([entity("same", 0, {"a": 1.0}, tenant="t1"), entity("same", 0, {"a": 2.0}, tenant="t2")])]
    )
    q = store.querier()
    (r1,) = q.series(SeriesSelect(Scope("t1"), EntityFilter(ids=("same",))))
    (r2,) = q.series(SeriesSelect(Scope("t2"), EntityFilter(ids=("same",))))
    assert r1.sid != r2.sid
    assert q.series(SeriesSelect(Scope(""), EntityFilter(ids=("same",)))) == []


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_row_windows_match_a_brute_force_model(store, seed):
    """lastN/limit/offset over wide rows of many series, including the time
    threshold used when there are many series."""
    rng = random.Random(seed)
    model: list[tuple[int, int, str]] = []  # (t, rid order, entity)
    batch = []
    attrs = ["a", "b", "c"]
    for i in range(300):
        eid = f"e{rng.randrange(8)}"
        t = rng.randrange(200)  # plenty of equal times
        present = {a: float(i) for a in attrs if rng.random() < 0.6} or {"a": float(i)}
        batch.append(entity(eid, t, present))
        model.append((t, i, eid))
    store.write_sync([AppendSamples(batch)])
    if hasattr(store, "compact"):
        store.compact(full=False)
    q = store.querier()
    refs = q.series(SeriesSelect(SCOPE, EntityFilter()))
    sids = [r.sid for r in refs]
    for newest_first in (False, True):
        for limit, offset in [(1, 0), (5, 0), (7, 3), (50, 10), (400, 0), (3, 298)]:
            rows = q.raw_rows(
                RowsRead(
                    sids,
                    TimeRange(),
                    newest_first=newest_first,
                    limit=limit,
                    offset=offset,
                    one_per_row=False,
                    attrs_per_row=3,
                )
            )
            got = []
            for _sid, rid, iso, *_ in rows:
                if not got or got[-1][0] != rid:
                    got.append((rid, iso))
            ordered = sorted(model, reverse=newest_first)
            want = ordered[offset : offset + limit]
            want.sort()
            assert [iso[17:19] for _rid, iso in got] == [
                f"{(T0 + timedelta(seconds=t)).second:02d}" for t, _i, _e in want
            ]
            assert len(got) == len(want)
