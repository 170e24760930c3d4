"""Every start-up failure of ``serve`` (and of the offline commands) is one
``error: ...`` line and a non-zero exit, not a traceback.

Real processes throughout: a DuckDB file held by another process, a
directory nobody may write, a PostgreSQL server that is not there, a
database or role that does not exist. Before, each of these printed some 60
lines of uvicorn and driver traceback.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.support.cli import run_cli
from tests.support.duckdb_holder import held_duckdb
from tests.support.server import free_port
from tsdb_service import __version__


def assert_one_line(done: subprocess.CompletedProcess, *needles: str, status: int = 2) -> str:
    assert done.returncode == status, done.stdout + done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), done.stderr
    for needle in needles:
        assert needle in lines[0], lines[0]
    return lines[0]


@pytest.fixture
def locked_duckdb(tmp_path):
    """A DuckDB file held open by another process (its pid, its path)."""
    path = tmp_path / "held.duckdb"
    with held_duckdb(path) as pid:
        yield pid, path


def test_a_duckdb_file_held_by_another_process(locked_duckdb):
    pid, path = locked_duckdb
    assert_one_line(
        run_cli("serve", "--db", str(path), "--port", str(free_port())), str(path), "another process", f"PID {pid}"
    )
    assert_one_line(run_cli("compact", "--db", str(path)), "another process")
    assert_one_line(run_cli("migrate", "--db", str(path)), "another process")


def test_a_lifespan_failure_inside_uvicorn_is_one_line(locked_duckdb):
    """The race the pre-flight check cannot close: the store fails to open in
    the application's start-up, inside uvicorn. One line, and uvicorn's exit 3."""
    _, path = locked_duckdb
    code = "import sys, uvicorn; uvicorn.run('tsdb_service.cli.main:serve_app', factory=True, port=int(sys.argv[1]))"
    env = {k: v for k, v in os.environ.items() if not k.startswith("TSDB_")} | {"TSDB_DB": str(path)}
    done = subprocess.run(
        [sys.executable, "-c", code, str(free_port())], capture_output=True, text=True, env=env, timeout=60
    )
    assert done.returncode == 3, done.stderr
    assert "Traceback" not in done.stderr, done.stderr
    errors = [line for line in done.stderr.splitlines() if "error: " in line]
    assert len(errors) == 1 and "another process" in errors[0], done.stderr
    assert len(done.stderr.strip().splitlines()) <= 5, done.stderr


def test_a_directory_that_cannot_be_written(tmp_path):
    blocker = tmp_path / "a-file"
    blocker.write_text("not a directory")
    assert_one_line(
        run_cli("serve", "--db", str(blocker / "tsdb.duckdb"), "--port", str(free_port())),
        "cannot create the directory",
    )
    assert_one_line(run_cli("serve", "--db", str(tmp_path), "--port", str(free_port())), "is a directory")
    assert_one_line(run_cli("serve", "--db", str(blocker), "--port", str(free_port())), "not a DuckDB database")


def test_a_read_only_directory():
    """sysfs refuses new files even to root: a real unwritable directory."""
    probe = Path("/sys/tsdb-probe.duckdb")
    try:
        probe.touch()
    except OSError:
        pass
    else:
        probe.unlink()
        pytest.skip("/sys is writable here")
    assert_one_line(run_cli("serve", "--db", str(probe), "--port", str(free_port())), "permission denied")


def test_postgresql_unreachable():
    url = f"postgresql://postgres@127.0.0.1:{free_port()}/tsdb"
    line = assert_one_line(run_cli("serve", "--db", url, "--port", str(free_port())), "cannot connect to PostgreSQL")
    assert "Connection refused" in line
    assert_one_line(run_cli("migrate", "--db", url), "cannot connect to PostgreSQL")


def test_postgresql_database_or_role_missing(pg_cluster):
    base = pg_cluster.url.rsplit("/", 1)[0]
    assert_one_line(
        run_cli("serve", "--db", f"{base}/no_such_db", "--port", str(free_port())),
        "database 'no_such_db' does not exist",
        "createdb",
    )
    no_role = base.replace("postgres@", "no_such_role@")
    assert_one_line(
        run_cli("serve", "--db", f"{no_role}/postgres", "--port", str(free_port())),
        "role 'no_such_role' does not exist",
    )


def test_a_password_never_reaches_the_message():
    url = f"postgresql://tsdb:s3cret@127.0.0.1:{free_port()}/tsdb"
    line = assert_one_line(run_cli("serve", "--db", url, "--port", str(free_port())))
    assert "s3cret" not in line and "tsdb:***@" in line


def test_compact_needs_an_existing_database(tmp_path):
    typo = tmp_path / "hsitory.duckdb"
    assert_one_line(run_cli("compact", "--db", str(typo)), f"{typo} does not exist")
    assert not typo.exists()


def test_serve_still_starts_on_a_good_database(tmp_path):
    """The checks add no failure of their own: a new file in a new directory starts."""
    port = free_port()
    db = tmp_path / "new" / "dir" / "tsdb.duckdb"
    env = {k: v for k, v in os.environ.items() if not k.startswith("TSDB_")}
    command = [
        sys.executable,
        "-m",
        "tsdb_service",
        "serve",
        "--db",
        str(db),
        "--host",
        "127.0.0.1",
        "--port",
        str(port),
    ]
    log = tmp_path / "serve.log"
    with log.open("wb") as sink:
        proc = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=sink, env=env)
    try:
        import httpx

        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            try:
                if httpx.get(f"http://127.0.0.1:{port}/health", timeout=2).status_code == 200:
                    break
            except httpx.HTTPError:
                time.sleep(0.2)
        else:
            pytest.fail("the service did not start")
    finally:
        proc.terminate()
        proc.wait(30)
    assert db.exists()
    # The log says which database was opened, by its absolute path.
    assert f"INFO:     tsdb-service {__version__} opened the DuckDB file {db.resolve()}" in log.read_text()


def test_the_log_names_a_postgresql_database_without_its_password():
    from tsdb_service.app import describe_database
    from tsdb_service.core.config import Settings

    said = describe_database(Settings(db="postgresql://tsdb:s3cret@db.example:5432/history"))
    assert said == "PostgreSQL database at postgresql://tsdb:***@db.example:5432/history"
