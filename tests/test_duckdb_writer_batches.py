"""DuckDB groups are written as Arrow batches, their rollups computed from
the same batch (``DuckDBAppender._commit_samples``, ``rollups.batch_partials``).

The writer retries a failed group one notification at a time, so a row left
over from the failed attempt would be stored twice, or a sample of a failed
notification stored after its 503. These tests make a group fail for real
(a value a column cannot hold) and check what the table holds afterwards;
they also pin that every time column and value reads back exactly, and that
the writer's rollups are those the SQL fold computes over the stored rows.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import time
from datetime import UTC, datetime, timedelta
from pathlib import Path

import orjson
import pytest

from tsdb_service.core.config import Settings
from tsdb_service.core.errors import Unavailable
from tsdb_service.core.model import AttrSample, EntitySample, Kind
from tsdb_service.storage import open_store
from tsdb_service.storage.duckdb.appender import DuckDBAppender
from tsdb_service.storage.duckdb.dialect import DuckDBDialect
from tsdb_service.storage.duckdb.store import DuckDBStore
from tsdb_service.storage.rollups import HOT, LEVELS, combine_partials, fold_sql
from tsdb_service.write.ops import AppendSamples

START = datetime(2026, 3, 1, 12, 0, 0, 123456, tzinfo=UTC)
DIALECT = DuckDBDialect()


def _entity(n: int, speed: object = None) -> EntitySample:
    return EntitySample(
        "rows",
        "/",
        f"urn:ngsi-ld:Lawnmower:{n}",
        "Lawnmower",
        START + timedelta(seconds=n),
        [AttrSample("speed", "Number", Kind.NUMBER, num=float(n) if speed is None else speed)],  # type: ignore[arg-type]
    )


def _count(store: DuckDBStore) -> int:
    return store.cursor().execute("SELECT count(*) FROM samples_all").fetchone()[0]


@pytest.fixture
def store(tmp_path: Path):
    """The database writer itself: no ingest log in front (its own poisoned
    entities: ``test_a_poisoned_entity_through_the_log_is_kept``)."""
    opened = open_store(Settings(db=str(tmp_path / "rows.duckdb"), ingest_log=False))
    assert isinstance(opened, DuckDBStore)
    try:
        yield opened
    finally:
        opened.close()


def test_a_failed_group_leaves_no_buffered_row_behind(store: DuckDBStore):
    store.write_sync([AppendSamples([_entity(0)])])  # the series exists: the group is samples only
    appender = DuckDBAppender(store)
    try:
        appender.stage(AppendSamples([_entity(1)]))
        appender.stage(AppendSamples([_entity(2, speed="not a number")]))
        with pytest.raises(Exception):  # noqa: B017 - DuckDB's or Python's conversion error, both fail the group
            appender.commit()
        appender.rollback()
        assert _count(store) == 1
        appender.stage(AppendSamples([_entity(3)]))
        appender.commit()
    finally:
        appender.close()
    times = [row[0] for row in store.cursor().execute("SELECT t FROM samples_all ORDER BY t").fetchall()]
    assert times == [(START + timedelta(seconds=n)).replace(tzinfo=None) for n in (0, 3)]


def test_the_writer_retries_a_poisoned_group_one_by_one(store: DuckDBStore):
    store.write_sync([AppendSamples([_entity(n)]) for n in range(3)])
    good = [AppendSamples([_entity(n)]) for n in range(10, 20)]
    bad = AppendSamples([_entity(99, speed="not a number")])
    with pytest.raises(Exception):  # noqa: B017 - the poisoned op fails alone
        store.write_sync([*good[:5], bad, *good[5:]])
    store.write_sync([AppendSamples([_entity(30)])])  # one writer: what was queued before is settled
    rows = store.cursor().execute("SELECT num, count(*) FROM samples_all GROUP BY num ORDER BY num").fetchall()
    assert rows == [(float(n), 1) for n in (0, 1, 2, *range(10, 20), 30)]


def test_every_time_column_reads_back_to_the_microsecond(store: DuckDBStore):
    moments = [
        datetime(1901, 12, 13, 20, 45, 52, 1, tzinfo=UTC),
        datetime(1970, 1, 1, tzinfo=UTC),
        datetime(2038, 1, 19, 3, 14, 8, 999999, tzinfo=UTC),
        datetime(9999, 12, 31, 23, 59, 59, 999999, tzinfo=UTC),
    ]
    entities = [
        EntitySample(
            "rows",
            "/",
            f"urn:ngsi-ld:Sensor:{i}",
            "Sensor",
            moment,
            [
                AttrSample(
                    "temperature",
                    "Property",
                    Kind.NUMBER,
                    num=0.1 + i,
                    observed_at=moment,
                    created_at=moment - timedelta(microseconds=1) if i else moment,
                    modified_at=moment,
                )
            ],
        )
        for i, moment in enumerate(moments)
    ]
    store.write_sync([AppendSamples(entities)])
    got = (
        store.cursor()
        .execute("SELECT t, observed_at, created_at, modified_at, num FROM samples_all ORDER BY t")
        .fetchall()
    )
    naive = [m.replace(tzinfo=None) for m in moments]
    assert [row[0] for row in got] == naive
    assert [row[1] for row in got] == naive
    assert [row[2] for row in got] == [naive[0], *(m - timedelta(microseconds=1) for m in naive[1:])]
    assert [row[4] for row in got] == [0.1 + i for i in range(len(moments))]


def test_groups_of_many_shapes_are_stored_exactly(store: DuckDBStore):
    """Groups filling different sets of columns, one after the other: every
    row of every shape is stored once, exactly."""
    appender = DuckDBAppender(store)
    expected = []
    try:
        for shape in range(32):  # which of num, txt, js, md, observedAt a sample fills
            moment = START + timedelta(minutes=shape)
            attr = AttrSample(
                "reading",
                "Property",
                Kind.NUMBER,
                num=float(shape) if shape & 1 else None,
                txt=f"t{shape}" if shape & 2 else None,
                js=f'{{"s":{shape}}}' if shape & 4 else None,
                md='{"unitCode":"CEL"}' if shape & 8 else None,
                observed_at=moment if shape & 16 else None,
            )
            appender.stage(AppendSamples([EntitySample("rows", "/", f"urn:x:{shape}", "X", moment, [attr])]))
            appender.commit()
            expected.append((moment.replace(tzinfo=None), attr.num, attr.txt, attr.js, attr.md))
    finally:
        appender.close()
    got = store.cursor().execute("SELECT t, num, txt, js, md FROM samples_all ORDER BY t").fetchall()
    assert got == expected


def test_a_poisoned_entity_through_the_log_is_kept(tmp_path: Path, monkeypatch):
    """Through the ingest log the poisoned entity was acknowledged: the rest
    of its batch is applied and it is kept in the rejected store."""
    monkeypatch.setattr("tsdb_service.write.logged.RETRY_DELAY_S", 0.001)
    monkeypatch.setattr("tsdb_service.write.logged.RETRY_MAX_DELAY_S", 0.002)
    logged = open_store(Settings(db=str(tmp_path / "logged.duckdb")))
    try:
        good = [AppendSamples([_entity(n)]) for n in range(10, 13)]
        bad = AppendSamples([_entity(99, speed="not a number")])
        with contextlib.suppress(Unavailable):  # the first syncs find the applier retrying
            logged.write_sync([*good[:2], bad, good[2]])
        deadline = time.monotonic() + 30
        while True:
            try:
                logged.sync()
                break
            except Unavailable:
                assert time.monotonic() < deadline
                time.sleep(0.01)
        rows = logged.cursor().execute("SELECT num FROM samples_all ORDER BY num").fetchall()
        assert rows == [(10.0,), (11.0,), (12.0,)]
        [kept] = logged.rejected(None, 10, 0)
        assert kept["error"] == "NotApplied" and "urn:" in kept["body"]
    finally:
        logged.close()


PAYLOADS = Path(__file__).parent / "payloads"


def _recorded_entities() -> list[EntitySample]:
    """Every recorded notification that parses (NGSIv2, NGSI-LD in each
    format, GeoJSON, NGSIv1), many times over with shifted times: numbers,
    texts, dates, structured values, geometries, relationships, metadata,
    observedAt and dataset ids."""
    from tsdb_service.core.errors import ParseError
    from tsdb_service.parse import parse_notification

    parsed = []
    for path in sorted(PAYLOADS.glob("*/*.json")):
        record = json.loads(path.read_text())
        body = orjson.dumps(record["body"]) if "body" in record else record["bodyText"].encode()
        with contextlib.suppress(ParseError):
            parsed += parse_notification(body, record["headers"], received_at=START)
    assert len(parsed) >= 8
    out = []
    for n in range(40):
        for e in parsed:
            shift = timedelta(seconds=n)
            attrs = [
                dataclasses.replace(a, observed_at=a.observed_at + shift if a.observed_at else None) for a in e.attrs
            ]
            out.append(dataclasses.replace(e, time_index=(e.time_index or START) + shift, attrs=attrs))
    return out


def test_the_writer_s_rollups_are_the_sql_fold_of_its_rows(store: DuckDBStore):
    """The partials the writer computes from each batch
    (``rollups.batch_partials``) equal, bucket by bucket, those the SQL fold
    (``rollups.fold_sql``, PostgreSQL's trigger) computes over the rows it
    stored: every kind of recorded payload, in groups of several sizes."""
    entities = _recorded_entities()
    start = 0
    for size in (1, 7, 100, 1000, len(entities)):
        if start < len(entities):
            store.write_sync([AppendSamples(entities[start : start + size])])
        start += size
    cur = store.cursor()

    def rollups() -> dict[int, list[tuple]]:
        return {
            level.code: cur.execute(
                combine_partials(DIALECT, f"(SELECT * FROM {HOT} WHERE level = {level.code})") + " ORDER BY ALL"
            ).fetchall()
            for level in LEVELS
        }

    written = rollups()
    assert cur.execute("SELECT count(*) FROM samples_all").fetchone()[0] == sum(len(e.attrs) for e in entities)
    assert all(written.values())
    cur.execute(f"DELETE FROM {HOT}")
    cur.execute(fold_sql(DIALECT, "samples_all"))
    assert rollups() == written
