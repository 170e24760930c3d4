"""Issue 27, settings that would leave the service open are refused at
start, in one line: an HMAC secret under 32 bytes, and ``*`` as a CORS
origin with no authentication (unless the operator says so). ``--help``
says that keys given as a flag show in ``ps``."""

from __future__ import annotations

import pytest

from tests.support.cli import run_cli
from tests.support.server import free_port
from tsdb_service.app import create_app
from tsdb_service.core.config import Settings


def _one_line(done, *needles: str) -> str:
    assert done.returncode == 2, done.stdout + done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), done.stderr
    for needle in needles:
        assert needle in lines[0], lines[0]
    return lines[0]


def test_a_short_hmac_secret_is_refused(tmp_path):
    db = str(tmp_path / "tsdb.duckdb")
    with pytest.raises(ValueError, match="at least 32 bytes"):
        create_app(Settings(db=db, jwt_key="secret"))
    with pytest.raises(ValueError, match="at least 32 bytes"):
        create_app(Settings(db=db, jwt_key="s" * 31))
    create_app(Settings(db=db, jwt_key="s" * 32))
    done = run_cli("serve", "--db", db, "--port", str(free_port()), env={"TSDB_JWT_KEY": "secret"})
    line = _one_line(done, "TSDB_JWT_KEY", "32 bytes")
    assert "secret'" not in line  # the secret itself is never echoed


def test_any_origin_without_authentication_is_refused_unless_meant(tmp_path):
    db = str(tmp_path / "tsdb.duckdb")
    with pytest.raises(ValueError, match="TSDB_CORS_ALLOW_UNAUTHENTICATED"):
        create_app(Settings(db=db, cors_origins="*"))
    with pytest.raises(ValueError):
        create_app(Settings(db=db, cors_origins="https://grafana.example.org, *"))
    create_app(Settings(db=db, cors_origins="*", cors_allow_unauthenticated=True))
    create_app(Settings(db=db, cors_origins="*", api_keys="reader-0123456789abcdef:read"))
    create_app(Settings(db=db, cors_origins="https://grafana.example.org"))
    done = run_cli("serve", "--db", db, "--port", str(free_port()), "--cors-origins", "*")
    _one_line(done, "--cors-origins (TSDB_CORS_ORIGINS) is *", "TSDB_CORS_ALLOW_UNAUTHENTICATED")


def test_help_steers_keys_away_from_the_command_line():
    done = run_cli("serve", "--help")
    text = " ".join(done.stdout.split())
    assert "show in ps" in text and "--api-keys-file" in text
