"""Every setting is validated before anything starts: one ``error: ...`` line
naming the flag and its ``TSDB_*`` variable, exit status 2, nothing created.

Each case runs the real command (``python -m tsdb_service``) as a subprocess,
the way an operator meets it. A ``--db`` that is neither a file path nor a
``postgresql://`` URL used to become a DuckDB file of that name (and data was
acknowledged into it); ``--port 99999`` used to listen on 34463.
"""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from tsdb_service.core.config import SettingsError, load_settings


def run_cli(*args: str, env: dict | None = None, cwd=None, timeout: float = 60) -> subprocess.CompletedProcess:
    clean = {k: v for k, v in os.environ.items() if not k.startswith("TSDB_")}
    return subprocess.run(
        [sys.executable, "-m", "tsdb_service", *args],
        capture_output=True,
        text=True,
        env=clean | (env or {}),
        cwd=cwd,
        timeout=timeout,
    )


def assert_usage_error(done: subprocess.CompletedProcess, *needles: str) -> None:
    assert done.returncode == 2, done.stdout + done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), done.stderr
    for needle in needles:
        assert needle in lines[0], lines[0]


@pytest.mark.parametrize(
    ("args", "needles"),
    [
        (["--port", "99999"], ["--port (TSDB_PORT)", "65535"]),
        (["--port", "0"], ["--port (TSDB_PORT)"]),
        (["--port", "http"], ["--port (TSDB_PORT)", "integer"]),
        (["--workers", "0"], ["--workers (TSDB_WORKERS)"]),
        (["--log-level", "loud"], ["--log-level (TSDB_LOG_LEVEL)", "debug"]),
        (["--db", "postgress://u@h/db"], ["--db (TSDB_DB)", "postgress://"]),
        (["--db", "mysql://u@h/db"], ["--db (TSDB_DB)", "mysql://"]),
        (["--db", "http://h/db"], ["--db (TSDB_DB)", "http://"]),
        (["--db", "postgresql:/oops"], ["--db (TSDB_DB)", "postgresql://user@host:port/database"]),
        (["--max-body-bytes", "10"], ["--max-body-bytes (TSDB_MAX_BODY_BYTES)"]),
        (["--host", " "], ["--host (TSDB_HOST)"]),
    ],
)
def test_serve_refuses_an_invalid_setting_in_one_line(tmp_path, args, needles):
    done = run_cli("serve", *args, cwd=tmp_path)
    assert_usage_error(done, *needles)
    assert list(tmp_path.iterdir()) == [], "nothing may be created for a refused setting"


def test_an_invalid_variable_is_refused_like_a_flag(tmp_path):
    done = run_cli("serve", env={"TSDB_PORT": "70000", "TSDB_DB": "mysql://x"}, cwd=tmp_path)
    assert_usage_error(done, "--port (TSDB_PORT)", "--db (TSDB_DB)")


@pytest.mark.parametrize(
    "command",
    [["migrate"], ["compact"], ["copy", "--to", "x.duckdb", "--from"], ["copy", "--from", "x.duckdb", "--to"]],
)
def test_every_command_refuses_an_unknown_scheme(tmp_path, command):
    done = run_cli(*command, *(["--db"] if command[0] != "copy" else []), "postgress://u@h/db", cwd=tmp_path)
    assert_usage_error(done, "postgress://")
    assert not (tmp_path / "postgress:").exists()


@pytest.mark.parametrize(
    "db",
    [
        "./data/tsdb.duckdb",
        "/var/lib/tsdb/h.duckdb",
        "C:/data/h.duckdb",
        ":memory:",
        "postgresql://u@h/db",
        "postgres://u:p@h:5433/db?sslmode=require",
        "./odd:name.duckdb",
    ],
)
def test_file_paths_and_postgres_urls_are_accepted(db):
    assert load_settings(db=db).db == db


def test_log_level_is_case_insensitive():
    assert load_settings(log_level="DEBUG").log_level == "debug"
    with pytest.raises(SettingsError):
        load_settings(log_level="verbose")


def test_demo_validates_its_db_and_port(tmp_path):
    assert_usage_error(run_cli("demo", "--db", "mysql://h/db", "--duration", "1", cwd=tmp_path), "mysql://")
    done = run_cli("demo", "--port", "99999", "--duration", "1", cwd=tmp_path)
    assert done.returncode == 2 and "--port" in done.stderr and "65535" in done.stderr, done.stderr
    assert list(tmp_path.iterdir()) == []
