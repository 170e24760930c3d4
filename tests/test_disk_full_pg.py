"""Disk full on PostgreSQL: refused writes say so truthfully, /health fails meanwhile.

The test database lives in a tablespace on a small tmpfs of the private test
cluster (its WAL stays on the cluster's own disk), so filling the tmpfs makes
every table extension fail with ``disk_full`` (SQLSTATE 53100). Each refused
notification must be a 503 "nothing was stored" and really not be stored,
``/health`` must fail while writes are refused and pass once one succeeds
again, and every acknowledged notification must be stored exactly once.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from pathlib import Path

import pytest

from tests.support.disk_full import (
    ENTITY,
    HEADERS,
    READ_HEADERS,
    Outcomes,
    check_exactly_once,
    health,
    stored_seqs,
    wait_healthy,
)
from tests.support.tmpfs import fill, small_tmpfs

MAX_POSTS = 3000


def _wanted() -> bool:
    return "postgresql" in os.environ.get("TSDB_TEST_BACKENDS", "duckdb,postgresql")


@pytest.fixture
def small_pg_database(request, tmp_path):
    """A database whose tables live on a 24 MB tmpfs; yields (url, disk)."""
    if not _wanted():
        pytest.skip("PostgreSQL not among TSDB_TEST_BACKENDS")
    import psycopg

    cluster = request.getfixturevalue("pg_cluster")
    # The cluster's user must reach the mount point: not under pytest's root-only directory.
    mount_point = Path(tempfile.mkdtemp(prefix="tsdb-pgdisk-"))
    mount_point.chmod(0o755)
    request.addfinalizer(lambda: shutil.rmtree(mount_point, ignore_errors=True))
    with small_tmpfs(mount_point / "disk", "24m", mode="0700") as disk:
        if os.geteuid() == 0:
            shutil.chown(disk, "postgres", "postgres")  # the cluster runs as postgres
        name = f"diskfull_{os.getpid()}_{abs(hash(str(tmp_path))) % 10**6}"
        with psycopg.connect(cluster.url, autocommit=True) as admin:
            admin.execute(f"CREATE TABLESPACE {name} LOCATION '{disk}'")
            admin.execute(f"CREATE DATABASE {name} TABLESPACE {name}")
        try:
            yield f"postgresql://postgres@127.0.0.1:{cluster.port}/{name}", disk
        finally:
            with psycopg.connect(cluster.url, autocommit=True) as admin:
                admin.execute(f"DROP DATABASE IF EXISTS {name} WITH (FORCE)")
                admin.execute(f"DROP TABLESPACE IF EXISTS {name}")


def poster(client):
    def post(method: str, path: str, body: bytes | None):
        headers = HEADERS if method == "POST" else READ_HEADERS
        response = client.request(method, path, content=body, headers=headers)
        assert response.status_code != 500, response.text
        return response.status_code, json.loads(response.content or b"{}")

    return post


def test_refused_writes_on_a_full_tablespace_are_reported_truthfully(small_pg_database, client_factory):
    url, disk = small_pg_database
    with client_factory(url) as client:
        post = poster(client)
        outcomes = Outcomes()
        for _ in range(5):
            assert outcomes.send(post) == 200
        filler = fill(disk, leave=64 * 1024)
        for _ in range(MAX_POSTS):
            if outcomes.send(post) == 503:
                break
        else:
            raise AssertionError(f"{MAX_POSTS} notifications fitted in 64 kB")
        assert "nothing was stored" in outcomes.bodies[-1]["description"], outcomes.bodies[-1]

        status, report = health(post)
        assert status == 503 and report["status"] == "fail", report
        assert "refuses writes" in report["output"], report
        # Reads do not need space: they keep working.
        status, body = post("GET", f"/v2/entities/{ENTITY}/attrs/seq?limit=10000", None)
        assert status == 200, body

        filler.unlink()
        wait_healthy(post, outcomes)
        for _ in range(20):
            assert outcomes.send(post) == 200
        assert not outcomes.unsure  # the connection never broke: every outcome is known
        check_exactly_once(outcomes, stored_seqs(post))


def test_the_writer_reconnects_when_its_connection_is_killed(backend, store_url, client_factory):
    """A restarted server or a cut connection must not fail every later write."""
    if backend != "postgresql":
        pytest.skip("PostgreSQL writer connections")
    import psycopg

    from tsdb_service.storage.postgres.appender import WRITER_APPLICATION_NAME

    with client_factory(store_url) as client:
        post = poster(client)
        outcomes = Outcomes()
        assert outcomes.send(post) == 200
        with psycopg.connect(store_url, autocommit=True) as admin:
            killed = admin.execute(
                "SELECT count(pg_terminate_backend(pid)) FROM pg_stat_activity "
                "WHERE datname = current_database() AND application_name = %s",
                [WRITER_APPLICATION_NAME],
            ).fetchone()[0]
        assert killed >= 1
        for _ in range(10):
            assert outcomes.send(post) == 200
        assert health(post)[0] == 200
        check_exactly_once(outcomes, stored_seqs(post))
