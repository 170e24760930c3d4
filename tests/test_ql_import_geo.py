"""Geometries QuantumLeap kept in PostGIS come back as QuantumLeap answers them.

QuantumLeap on TimescaleDB stores every geo attribute in a PostGIS
``geometry`` column and answers ``geo:json`` as GeoJSON and the simple
location types as ``"lat, lon"`` text (lists of them for lines, polygons
and boxes). Needs PostGIS in the test PostgreSQL; skipped with the reason
when it is not installed and cannot be (the conversion itself is covered without a
database by test_ql_import_rows.py).
"""

from __future__ import annotations

from datetime import UTC, datetime

import psycopg
import pytest

from tests.support.apt import apt_install
from tsdb_service.cli.main import main
from tsdb_service.commands.quantumleap.layout import has_postgis, write_entities

T0 = datetime(2024, 5, 1, 10, tzinfo=UTC)
VALUES = {
    "position": ("geo:json", {"type": "Point", "coordinates": [-3.7038, 40.4168]}),
    "location": ("geo:point", "40.4168, -3.7038"),
    "route": ("geo:line", ["40.0, -3.0", "41.0, -4.0"]),
    "area": ("geo:polygon", ["40.0, -3.0", "41.0, -3.0", "41.0, -4.0", "40.0, -3.0"]),
    "bounds": ("geo:box", ["40.63913831188419, -8.653321266174316", "40.63881265804603, -8.653149604797363"]),
}


def _create_postgis(conn: psycopg.Connection) -> None:
    """PostGIS in this database: Debian's package for the server's major
    version is installed when it is missing and we may (root, apt-get)."""
    try:
        conn.execute("CREATE EXTENSION IF NOT EXISTS postgis")
        return
    except psycopg.Error as exc:
        missing = exc.diag.message_primary
    major = int(conn.execute("SHOW server_version_num").fetchone()[0]) // 10000
    why = apt_install(f"postgresql-{major}-postgis-3")
    if why is not None:
        pytest.skip(f"PostGIS is not installed in the test PostgreSQL ({missing}); {why}")
    conn.execute("CREATE EXTENSION IF NOT EXISTS postgis")


@pytest.fixture
def postgis_source(pg_cluster) -> str:
    url = pg_cluster.database("ql_geo_source")
    with psycopg.connect(url, autocommit=True) as conn:
        _create_postgis(conn)
        assert has_postgis(conn)
        entity = {"id": "Mower:1", "type": "Mower", **{k: {"type": t, "value": v} for k, (t, v) in VALUES.items()}}
        write_entities(conn, "geo", [(entity, T0, "/")])
    return url


def test_geometries_answer_as_in_quantumleap(postgis_source, client_factory, tmp_path):
    db = str(tmp_path / "t.duckdb")
    assert main(["import", "quantumleap", "--from", postgis_source, "--db", db, "--quiet"]) == 0
    headers = {"Fiware-Service": "geo"}
    with client_factory(db) as client:
        body = client.get("/v2/entities/Mower:1", headers=headers).json()
        near = client.get(
            "/v2/entities?georel=near;maxDistance:1000&geometry=point&coords=40.4168,-3.7038", headers=headers
        )
    answered = {a["attrName"]: a["values"][0] for a in body["attributes"]}
    assert answered == {name: value for name, (_, value) in VALUES.items()}
    assert near.status_code == 200 and [e["id"] for e in near.json()] == ["Mower:1"]
