"""PostgreSQL replicas writing the same series at once keep rollups exact.

Two stores on one database (two replicas, three writer threads each) write
notifications of the same entities, in the same minutes and hours, while
one of them deletes ranges and both merge hot rows: every write appends its
partials in its own transaction (the trigger), merges and recomputes take
the rollup lock, and a recompute reads raw and drops hot rows in one
snapshot. Afterwards every bucket equals its raw samples; no update is lost
or counted twice. Also pinned: the trigger's body is the SQL the code folds
with (``storage.rollups.fold_sql``), word for word.
"""

from __future__ import annotations

import re
import threading
from datetime import UTC, datetime, timedelta

import psycopg
import pytest

from tests.support.rollups import bucket_count, differences
from tsdb_service.core.config import Settings
from tsdb_service.core.model import AttrSample, EntitySample, Kind
from tsdb_service.core.query import EntityFilter, Scope
from tsdb_service.read.requests import SeriesSelect
from tsdb_service.storage import open_store
from tsdb_service.storage.postgres.dialect import PostgresDialect
from tsdb_service.storage.rollups import fold_sql
from tsdb_service.write.ops import AppendSamples, DeleteSamples

T0 = datetime(2024, 5, 1, 10, 58, tzinfo=UTC)


@pytest.fixture
def url(store_url, backend) -> str:
    if backend != "postgresql":
        pytest.skip("PostgreSQL only: a DuckDB file has one writing process")
    return store_url


def batch(writer: int, k: int) -> list[EntitySample]:
    """Both replicas write the same two entities, interleaved in time."""
    out = []
    for e in ("R1", "R2"):
        at = T0 + timedelta(seconds=7 * k + writer)  # within the same minutes and hours
        attrs = [
            AttrSample("speed", "Number", Kind.NUMBER, num=(k % 13) / 8 + writer),
            AttrSample("ticks", "Integer", Kind.INTEGER, num=float(k)),
        ]
        out.append(EntitySample("", "/", e, "Robot", at, attrs))
    return out


def test_two_replicas_writing_the_same_series_lose_and_double_nothing(url):
    a, b = open_store(Settings(db=url)), open_store(Settings(db=url))
    try:
        a.write_sync([AppendSamples(batch(0, 0))])  # the series exist before the race
        failures: list[BaseException] = []

        def write(store, writer: int) -> None:
            try:
                for k in range(1, 120):
                    store.write_sync([AppendSamples(batch(writer, k))])
            except BaseException as exc:
                failures.append(exc)

        def churn() -> None:
            try:
                sids = tuple(r.sid for r in a.querier().series(SeriesSelect(Scope(""), EntityFilter(ids=("R1",)))))
                for k in range(6):
                    start = T0 + timedelta(seconds=40 * k)
                    a.write_sync([DeleteSamples(sids, start, start + timedelta(seconds=15))])
                    (a if k % 2 else b).merge_rollups(50)
            except BaseException as exc:
                failures.append(exc)

        threads = [
            threading.Thread(target=write, args=(a, 1)),
            threading.Thread(target=write, args=(b, 2)),
            threading.Thread(target=churn),
        ]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        assert not failures
        assert not differences(a)
        a.compact()  # every hot row merged
        assert not differences(b)
        assert bucket_count(a) > 0
    finally:
        a.close()
        b.close()


def test_the_trigger_folds_with_the_code_s_sql(url):
    open_store(Settings(db=url)).close()  # migrated
    with psycopg.connect(url) as conn:
        row = conn.execute("SELECT prosrc FROM pg_proc WHERE proname = 'rollups_fold'").fetchone()
    assert row is not None
    folded = re.sub(r"\s+", " ", fold_sql(PostgresDialect(), "changed"))
    assert re.sub(r"\s+", " ", row[0]).strip() == f"BEGIN {folded}; RETURN NULL; END"
