"""PostgreSQL's ``geo_extents`` (migration 0006, tsdb_service/storage/postgres/extents.py).

Geo-queries find their candidate entities in this table, so a position
missing from it would silently drop matching samples. Pinned here: a
database written before the table existed gets it backfilled by the
migration; two replicas writing the same entity's positions compose (each
grows the stored extent, whatever the other knows); extents only grow; an
entity parked inside the area, decided from its extent alone, still starts
matching at its first position, also after a delete.
"""

from __future__ import annotations

import os

import psycopg
import pytest

pytestmark = pytest.mark.skipif(
    "postgresql" not in os.environ.get("TSDB_TEST_BACKENDS", "postgresql"),
    reason="PostgreSQL is not among TSDB_TEST_BACKENDS",
)

AREA = "georel=coveredBy&geometry=box&coords=41.370,2.170;41.380,2.185"
NEAR_FAR = "georel=near;maxDistance:500&geometry=point&coords=41.4500,2.2500"
INSIDE, FAR = (41.375, 2.178), (41.450, 2.250)


def _note(eid: str, minute: int, where: tuple[float, float] | None, reading: float) -> dict:
    entity = {
        "id": eid,
        "type": "Robot",
        "TimeInstant": {"type": "DateTime", "value": f"2024-05-01T10:{minute:02d}:00Z"},
        "speed": {"type": "Number", "value": reading},
    }
    if where is not None:
        entity["location"] = {"type": "geo:point", "value": f"{where[0]}, {where[1]}"}
    return {"data": [entity]}


def _readings(client, geo: str, eid: str = "r1") -> list[float]:
    response = client.get(f"/v2/entities/{eid}/attrs/speed?type=Robot&{geo}")
    if response.status_code == 404:
        return []
    assert response.status_code == 200, response.text
    body = response.json()
    return [] if body == [] else body["values"]


def _extents(url: str) -> list[tuple]:
    with psycopg.connect(url) as conn:
        return conn.execute("SELECT min_lon, min_lat, max_lon, max_lat FROM geo_extents ORDER BY sid").fetchall()


def test_migration_backfills_a_database_written_before_it(pg_cluster, client_factory, notify):
    url = pg_cluster.database("geo_extents_backfill")
    with client_factory(url) as client:
        for minute, where in enumerate([FAR, INSIDE, None, FAR]):
            notify(client, _note("r1", minute, where, float(minute)))
    with psycopg.connect(url, autocommit=True) as conn:  # as if written before migration 0006
        conn.execute("DROP TABLE geo_extents")
        conn.execute("DELETE FROM schema_migrations WHERE version = 6")
    with client_factory(url) as client:
        assert _extents(url) == [(2.178, 41.375, 2.25, 41.45)]
        assert _readings(client, AREA) == [1.0, 2.0]
        assert _readings(client, NEAR_FAR) == [0.0, 3.0]


def test_two_replicas_grow_one_extent(pg_cluster, client_factory, notify):
    url = pg_cluster.database("geo_extents_replicas")
    with client_factory(url) as one, client_factory(url) as two:
        notify(one, _note("r1", 0, INSIDE, 0.0))
        notify(two, _note("r1", 1, FAR, 1.0))  # two has never seen r1's extent
        notify(one, _note("r1", 2, INSIDE, 2.0))  # inside what one knows: no statement
        notify(one, _note("r1", 3, FAR, 3.0))  # one does not know FAR yet: upserted, no change
        assert _extents(url) == [(2.178, 41.375, 2.25, 41.45)]
        for client in (one, two):
            assert _readings(client, AREA) == [0.0, 2.0]
            assert _readings(client, NEAR_FAR) == [1.0, 3.0]


def test_parked_inside_matches_from_its_first_position(pg_cluster, client_factory, notify):
    """The extent lies inside the area: decided without reading positions,
    starting at the first one (readings before it have no location)."""
    url = pg_cluster.database("geo_extents_parked")
    with client_factory(url) as client:
        notify(client, _note("r1", 0, None, 0.0))
        for minute in range(1, 5):
            notify(client, _note("r1", minute, INSIDE if minute % 2 else None, float(minute)))
        assert _readings(client, AREA) == [1.0, 2.0, 3.0, 4.0]
        response = client.delete("/v2/entities/r1?type=Robot&fromDate=2024-05-01T10:00:30Z&toDate=2024-05-01T10:01:30Z")
        assert response.status_code == 204, response.text
        # The first position is gone; the next one (minute 3) starts the match.
        assert _readings(client, AREA) == [3.0, 4.0]
        assert _extents(url) == [(2.178, 41.375, 2.178, 41.375)]  # extents never shrink
