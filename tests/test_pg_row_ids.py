"""PostgreSQL row ids come from blocks reserved from ``sample_rid_seq``
(tsdb_service/storage/postgres/ids.py, ``RowIds``), and a group of plain
samples of known series is one autocommit COPY.

Reads group a notification's attributes into one row by ``rid`` and order
samples of one instant by it, so pinned here: ids are unique across writer
threads and across stores sharing the sequence (replicas); each take is
increasing and later takes get larger ids; every attribute of one entity
sample shares its id, two samples never share one; and samples arriving
through both commit paths (new series: a transaction; known series: the
single COPY) are all stored exactly once.
"""

from __future__ import annotations

import itertools
import os
import random
import threading

import psycopg
import pytest

from tsdb_service.storage.postgres.ids import RowIds
from tsdb_service.storage.postgres.store import migrate_url

pytestmark = pytest.mark.skipif(
    "postgresql" not in os.environ.get("TSDB_TEST_BACKENDS", "postgresql"),
    reason="PostgreSQL is not among TSDB_TEST_BACKENDS",
)

HEADERS = {"Fiware-Service": "rowids"}


def _reserver(conn: psycopg.Connection):
    def reserve(n: int) -> list[int]:
        rows = conn.execute("SELECT nextval('sample_rid_seq') FROM generate_series(1, %s)", [n]).fetchall()
        return sorted(row[0] for row in rows)

    return reserve


def _take_concurrently(url: str, pools: list[RowIds], threads: int, takes: int) -> list[list[int]]:
    """Every take of ``threads`` threads (each on its own connection, on
    the pools in turn), in the order they returned per pool."""
    taken: list[list[int]] = []
    lock = threading.Lock()

    def work(i: int) -> None:
        rng = random.Random(i)
        pool = pools[i % len(pools)]
        with psycopg.connect(url, autocommit=True) as conn:
            reserve = _reserver(conn)
            for _ in range(takes):
                ids = pool.take(rng.randint(1, 70), reserve)
                with lock:
                    taken.append(ids)

    workers = [threading.Thread(target=work, args=(i,)) for i in range(threads)]
    for w in workers:
        w.start()
    for w in workers:
        w.join()
    return taken


def test_ids_are_unique_and_takes_do_not_interleave(pg_cluster):
    url = pg_cluster.database("row_ids_threads")
    migrate_url(url)
    pool = RowIds(block=100)  # small blocks: many reservations race
    taken = _take_concurrently(url, [pool], threads=3, takes=200)
    flat = [rid for ids in taken for rid in ids]
    assert len(flat) == len(set(flat))
    assert all(ids == sorted(ids) for ids in taken)
    # One pool hands out its ids in order: a take's ids all lie below the next one's.
    spans = sorted((min(ids), max(ids)) for ids in taken)
    assert all(a[1] < b[0] for a, b in itertools.pairwise(spans))


def test_two_replicas_sharing_the_sequence_never_share_an_id(pg_cluster):
    url = pg_cluster.database("row_ids_replicas")
    migrate_url(url)
    taken = _take_concurrently(url, [RowIds(block=64), RowIds(block=64)], threads=4, takes=100)
    flat = [rid for ids in taken for rid in ids]
    assert len(flat) == len(set(flat))


def _note(eid: str, minute: int, value: int) -> dict:
    return {
        "data": [
            {
                "id": eid,
                "type": "Counter",
                "TimeInstant": {"type": "DateTime", "value": f"2024-05-01T10:{minute:02d}:00Z"},
                "a": {"type": "Number", "value": value},
                "b": {"type": "Text", "value": f"v{value}"},
                "location": {"type": "geo:point", "value": f"41.{value:03d}, 2.1"},
            }
        ]
    }


def test_every_entity_sample_has_one_id_of_its_own(pg_cluster, client_factory, notify):
    url = pg_cluster.database("row_ids_samples")
    with client_factory(url) as client:
        for minute in range(20):  # first: new series (a transaction); then known ones (one COPY)
            for e in range(3):
                notify(client, _note(f"c{e}", minute, minute * 3 + e), HEADERS)
        body = client.get("/v2/entities/c1/attrs/b?type=Counter", headers=HEADERS).json()
        assert body["values"] == [f"v{m * 3 + 1}" for m in range(20)]
    with psycopg.connect(url) as conn:
        rows = conn.execute(
            "SELECT rid, count(*), count(DISTINCT sid), min(t) = max(t) FROM samples GROUP BY rid"
        ).fetchall()
        extents = conn.execute("SELECT count(*) FROM geo_extents").fetchone()
    assert len(rows) == 60  # one id per entity sample
    # a, b, location and TimeInstant (stored as an attribute too)
    assert all(n == 4 and distinct == 4 and same_t for _, n, distinct, same_t in rows), rows[:3]
    assert extents == (3,)
