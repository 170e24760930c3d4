"""Every setting is validated before anything starts: one ``error: ...`` line
naming the flag and its ``TSDB_*`` variable, exit status 2, nothing created.

Each case runs the real command (``python -m tsdb_service``) as a subprocess,
the way an operator meets it. A ``--db`` that is neither a file path nor a
``postgresql://`` URL used to become a DuckDB file of that name (and data was
acknowledged into it); ``--port 99999`` used to listen on 34463.
"""

from __future__ import annotations

import pytest

from tests.support.cli import assert_usage_error, run_cli
from tsdb_service.core.config import SettingsError, load_settings


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


@pytest.fixture
def listening_port():
    """A port another socket already listens on."""
    import socket

    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        sock.listen()
        yield sock.getsockname()[1]


def test_serve_refuses_a_port_in_use_before_creating_anything(tmp_path, listening_port):
    done = run_cli("serve", "--host", "127.0.0.1", "--port", str(listening_port), cwd=tmp_path)
    assert_usage_error(done, "--port (TSDB_PORT)", f"127.0.0.1:{listening_port} is already in use")
    assert list(tmp_path.iterdir()) == [], "nothing may be created when the port is taken"


@pytest.mark.parametrize(
    ("host", "needle"),
    [("999.1.1.1", "cannot listen on '999.1.1.1'"), ("192.0.2.77", "not an address of this machine")],
)
def test_serve_refuses_a_host_it_cannot_listen_on(tmp_path, host, needle):
    assert_usage_error(run_cli("serve", "--host", host, cwd=tmp_path), "--host (TSDB_HOST)", needle)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(
    ("args", "needles"),
    [
        (["--api-keys", "short:read"], ["--api-keys (TSDB_API_KEYS)", "at least 16"]),
        (["--api-keys", "long-enough-key-1234:superuser"], ["--api-keys (TSDB_API_KEYS)", "read, write, admin"]),
        (["--api-keys-file", "/nonexistent/keys"], ["--api-keys-file (TSDB_API_KEYS_FILE)", "cannot read"]),
        (["--jwt-key", "s" * 32, "--jwt-algorithms", "FOO"], ["--jwt-algorithms (TSDB_JWT_ALGORITHMS)", "FOO"]),
        (["--jwt-key", "s" * 32, "--jwt-algorithms", "RS256"], ["--jwt-algorithms", "cannot be used"]),
        (["--jwt-algorithms", "RS256"], ["TSDB_JWT_ALGORITHMS", "no token is verified"]),
        (["--jwt-audience", "tsdb"], ["TSDB_JWT_AUDIENCE", "TSDB_JWT_JWKS_URL or TSDB_JWT_KEY"]),
        (["--jwt-jwks-url", "notaurl"], ["--jwt-jwks-url (TSDB_JWT_JWKS_URL)", "not an http(s) URL"]),
        (["--jwt-jwks-url", "ftp://kc/certs"], ["--jwt-jwks-url (TSDB_JWT_JWKS_URL)", "not an http(s) URL"]),
        (["--jwt-key", "-----BEGIN PUBLIC KEY-----\nnope\n-----END PUBLIC KEY-----"], ["not a PEM public key"]),
        (["--ngsild-contexts", "garbage"], ["--ngsild-contexts (TSDB_NGSILD_CONTEXTS)", "URL=path"]),
        (["--ngsild-contexts", "garbage=./c.jsonld"], ["--ngsild-contexts", "'garbage' is not an http(s) URL"]),
        (["--ngsild-contexts", "https://ex.org/c.jsonld=/nonexistent.jsonld"], ["cannot read /nonexistent.jsonld"]),
    ],
)
def test_serve_refuses_bad_security_and_context_settings_in_one_line(tmp_path, args, needles):
    """Each used to be a 35-line traceback after the database was created, or was accepted."""
    done = run_cli("serve", *args, cwd=tmp_path)
    assert_usage_error(done, *needles)
    assert "Traceback" not in done.stderr
    assert list(tmp_path.iterdir()) == []


def test_a_local_context_file_that_is_not_json_is_refused(tmp_path):
    (tmp_path / "c.jsonld").write_text("{not json")
    done = run_cli("serve", "--ngsild-contexts", f"https://ex.org/c.jsonld={tmp_path / 'c.jsonld'}", cwd=tmp_path)
    assert_usage_error(done, "--ngsild-contexts", "is not JSON")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.jsonld"]


def test_a_setting_on_by_default_can_be_turned_off_by_its_flag(monkeypatch):
    """``--no-ingest-log`` exists: a bool setting that defaults to true had
    only its ``--ingest-log`` form, so only ``TSDB_INGEST_LOG`` could turn it off."""
    from tsdb_service.cli.main import _settings, build_parser

    monkeypatch.delenv("TSDB_INGEST_LOG", raising=False)
    parse = build_parser().parse_args
    assert _settings(parse(["serve", "--no-ingest-log"])).ingest_log is False
    assert _settings(parse(["serve", "--ingest-log"])).ingest_log is True
    assert _settings(parse(["serve", "--access-log"])).access_log is True
    with pytest.raises(SystemExit):
        parse(["serve", "--no-access-log"])  # off by default: no --no- form
