"""PostgreSQL's ``series_generation`` (migration 0010): the number of series
rows ever inserted (summed over a row per inserting session), moved by a
trigger in the inserting transaction, which
each replica's catalog reads to learn that another replica created series
(``PostgresQuerier._series_generation``) instead of counting the table.
Pinned here: the migration starts it at the existing count; it follows
inserts and not writes to known series; another replica's new series are
found through it; the catalog's check no longer counts ``series``."""

from __future__ import annotations

import os

import psycopg
import pytest

from tsdb_service.storage.postgres import querier as pg_querier

pytestmark = pytest.mark.skipif(
    "postgresql" not in os.environ.get("TSDB_TEST_BACKENDS", "postgresql"),
    reason="PostgreSQL is not among TSDB_TEST_BACKENDS",
)

HEADERS = {"Fiware-Service": "gen", "Fiware-ServicePath": "/"}


def _note(eid: str, minute: int, **attrs: float) -> dict:
    entity = {
        "id": eid,
        "type": "Robot",
        "TimeInstant": {"type": "DateTime", "value": f"2024-05-01T10:{minute:02d}:00Z"},
    }
    entity.update({name: {"type": "Number", "value": value} for name, value in attrs.items()})
    return {"data": [entity]}


def _generation(url: str) -> tuple[int, int]:
    """(the counter, the series rows)."""
    with psycopg.connect(url) as conn:
        [(n,)] = conn.execute("SELECT sum(n) FROM series_generation").fetchall()
        [(count,)] = conn.execute("SELECT count(*) FROM series").fetchall()
    return n, count


def _speeds(client, eid: str) -> list[float]:
    response = client.get(f"/v2/entities/{eid}/attrs/speed", headers=HEADERS)
    return response.json()["values"] if response.status_code == 200 else []


def test_the_migration_starts_at_the_existing_count(pg_cluster, client_factory, notify):
    url = pg_cluster.database("series_generation_backfill")
    with client_factory(url) as client:
        notify(client, _note("r1", 0, speed=1.0, load=2.0), HEADERS)
    with psycopg.connect(url, autocommit=True) as conn:  # as if written before migration 0010
        conn.execute("DROP TABLE series_generation")
        conn.execute("DROP FUNCTION series_generation_bump() CASCADE")
        conn.execute("DELETE FROM schema_migrations WHERE version = 10")
    with client_factory(url) as client:
        n, count = _generation(url)
        assert n == count > 0
        notify(client, _note("r2", 1, speed=3.0), HEADERS)  # new series: r2's speed and time index
        after, count_after = _generation(url)
        assert after == count_after > count


def test_it_follows_inserts_only(pg_cluster, client_factory, notify):
    url = pg_cluster.database("series_generation_inserts")
    with client_factory(url) as client:
        notify(client, _note("r1", 0, speed=1.0, load=2.0), HEADERS)
        n, count = _generation(url)
        assert n == count > 0
        for minute in range(1, 4):  # known series: no insert, no move
            notify(client, _note("r1", minute, speed=float(minute)), HEADERS)
        assert _generation(url) == (n, count)
        notify(client, _note("r1", 4, speed=4.0, heading=90.0), HEADERS)  # one new series
        assert _generation(url) == (n + 1, count + 1)


def test_another_replica_s_series_are_found(pg_cluster, client_factory, notify, monkeypatch):
    monkeypatch.setattr(pg_querier, "SERIES_CHECK_S", 0.0)  # check at every lookup
    url = pg_cluster.database("series_generation_replicas")
    with client_factory(url) as one, client_factory(url) as two:
        notify(one, _note("r1", 0, speed=1.0), HEADERS)
        assert _speeds(one, "r1") == [1.0]
        statements: list[str] = []
        querier = one.app.state.store.querier()
        fetch = querier._fetch

        def recording(sql, params, *args, **kwargs):
            statements.append(sql)
            return fetch(sql, params, *args, **kwargs)

        monkeypatch.setattr(querier, "_fetch", recording)
        notify(two, _note("r2", 1, speed=5.0), HEADERS)  # a series `one` has never seen
        listed = one.get("/v2/entities", headers=HEADERS, params={"type": "Robot", "options": "count"})
        assert sorted(entity["id"] for entity in listed.json()) == ["r1", "r2"]
        assert _speeds(one, "r2") == [5.0]
        assert any("series_generation" in sql for sql in statements)
        assert not any("count(*) FROM series" in sql for sql in statements)
