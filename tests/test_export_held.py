"""``tsdb-service export`` on a DuckDB file the running service holds.

DuckDB lets one process open a file, so the export cannot open it: it goes
through the service's ``GET /v2/export`` instead, found as the file's
holder, or at ``--url``; when the holder is no service it can reach, one
line says how to export. Real processes: a ``serve`` subprocess, a plain
DuckDB connection in another process, the real ``export`` command.
"""

from __future__ import annotations

import subprocess

import httpx
import pytest

from tests.support.cli import run_cli
from tests.support.duckdb_holder import held_duckdb
from tests.support.server import ServerProcess

NOTIFICATION = {
    "subscriptionId": "s",
    "data": [
        {"id": "R1", "type": "Robot", "battery": {"type": "Number", "value": 0.5}},
        {"id": "R2", "type": "Robot", "mode": {"type": "Text", "value": "=cmd"}},
    ],
}
KEY = "export-test-key-0123456789"


def _one_error(done: subprocess.CompletedProcess) -> str:
    assert done.returncode == 2, done.stdout + done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), done.stderr
    return lines[0]


@pytest.fixture
def serving(tmp_path):
    """A service holding its DuckDB file, with two samples stored."""
    with ServerProcess(tmp_path / "held.duckdb", extra_env={"TSDB_API_KEYS": f"{KEY}:read,write"}) as server:
        httpx.post(f"{server.url}/v2/notify", json=NOTIFICATION, headers={"X-Api-Key": KEY}).raise_for_status()
        yield server


def _export(server: ServerProcess, *args: str, token: str | None = KEY) -> subprocess.CompletedProcess:
    env = {"TSDB_CLIENT_TOKEN": token} if token else {}
    return run_cli("export", "--db", str(server.db_path), *args, env=env)


def test_a_file_the_service_holds_is_exported_through_it(serving, tmp_path):
    out = tmp_path / "robots.csv"
    done = _export(serving, "--out", str(out), "--type", "Robot")
    assert done.returncode == 0, done.stderr
    assert done.stderr.strip() == (
        f"{serving.db_path} is held by the service at {serving.url} (PID {serving.pid}): exporting through it"
    )
    assert f"exported {serving.url}/v2/export?type=Robot&format=csv to {out}" in done.stdout
    answer = httpx.get(f"{serving.url}/v2/export", params={"type": "Robot"}, headers={"X-Api-Key": KEY})
    assert out.read_bytes() == answer.content and b"'=cmd" in answer.content


def test_url_exports_through_the_service_named(serving, tmp_path):
    out = tmp_path / "all.parquet"
    done = run_cli("export", "--url", serving.url, "--out", str(out), env={"TSDB_CLIENT_TOKEN": KEY})
    assert done.returncode == 0, done.stderr
    import pyarrow.parquet as pq

    assert pq.read_table(out).num_rows == 2


def test_a_service_that_wants_a_credential_says_where_it_goes(serving, tmp_path):
    out = tmp_path / "x.csv"
    done = _export(serving, "--out", str(out), token=None)
    assert done.returncode == 2
    note, line = done.stderr.strip().splitlines()
    assert "exporting through it" in note
    assert "refused the export (401" in line and "set TSDB_CLIENT_TOKEN" in line, line
    assert not out.exists() and list(tmp_path.glob(".x.csv*")) == [], "nothing is left behind"


def test_a_holder_that_is_no_service_is_one_line(tmp_path):
    """A process holding the file that listens nowhere: the line says how to export."""
    path = tmp_path / "held.duckdb"
    out = tmp_path / "x.csv"
    with held_duckdb(path) as pid:
        line = _one_error(run_cli("export", "--db", str(path), "--out", str(out), "--type", "Robot"))
    assert f"{path} is held by another process (PID {pid})" in line, line
    assert "tsdb-service export --url http://HOST:PORT" in line, line
    assert "GET http://HOST:PORT/v2/export?type=Robot&format=csv" in line, line
    assert not out.exists()


def test_url_must_be_http(tmp_path):
    line = _one_error(run_cli("export", "--url", "tsdb:8668", "--out", str(tmp_path / "x.csv")))
    assert line == "error: --url tsdb:8668: give the service's http:// or https:// URL"
