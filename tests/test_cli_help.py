"""``tsdb-service --version``; every flag of every subcommand says its default
in its help; ``queries run`` against a service that is not there says so once."""

from __future__ import annotations

import argparse

import pytest

from tests.support.cli import run_cli
from tsdb_service import __version__
from tsdb_service.cli.main import build_parser


def test_version_flag():
    done = run_cli("--version")
    assert done.returncode == 0 and done.stdout.strip() == f"tsdb-service {__version__}"


def _subparsers(parser: argparse.ArgumentParser, prefix: str = ""):
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield f"{prefix}{name}", sub
                yield from _subparsers(sub, f"{prefix}{name} ")


COMMANDS = [name for name, _ in _subparsers(build_parser())]


@pytest.mark.parametrize("command", COMMANDS)
def test_every_flag_says_its_default(command):
    parser = dict(_subparsers(build_parser()))[command]
    for action in parser._actions:
        if not action.option_strings or isinstance(action, argparse._HelpAction | argparse._VersionAction):
            continue
        flag = action.option_strings[-1]
        assert action.help, f"{command} {flag} has no help"
        if action.required:
            continue
        if isinstance(action, argparse._StoreTrueAction):
            continue  # off unless given
        assert "default" in action.help or "env TSDB_" in action.help, f"{command} {flag}: {action.help!r}"


def test_serve_help_shows_defaults_and_variables():
    done = run_cli("serve", "--help")
    assert done.returncode == 0
    text = " ".join(done.stdout.split())
    for expected in (
        "--port PORT",
        "default 8668; env TSDB_PORT",
        "default ./data/tsdb.duckdb; env TSDB_DB",
        "--max-body-bytes",
        "env TSDB_MAX_BODY_BYTES",
        "--log-level",
        "default info",
    ):
        assert expected in text, expected


def test_demo_help_says_a_run_can_overrun():
    text = " ".join(run_cli("demo", "--help").stdout.split())
    assert "A run can overrun" in text and "live" in text


def test_queries_run_against_an_unreachable_service_says_so_once():
    from tests.support.server import free_port

    url = f"http://127.0.0.1:{free_port()}"
    done = run_cli("queries", "run", "--url", url)
    assert done.returncode == 2
    assert done.stderr.strip().splitlines() == [f"error: cannot reach {url}: [Errno 111] Connection refused"]
    assert "FAIL" not in done.stdout


def test_demo_feeding_an_unreachable_service_says_so_once():
    from tests.support.server import free_port

    url = f"http://127.0.0.1:{free_port()}"
    done = run_cli("demo", "--no-serve", "--url", url, "--duration", "1")
    assert done.returncode == 2
    assert done.stderr.strip().splitlines() == [f"error: cannot reach {url}: [Errno 111] Connection refused"]


def test_serve_placeholders_say_what_a_value_is():
    """Count and byte settings said ``TENANT`` (the last word of their name)."""
    usage = " ".join(run_cli("serve", "--help").stdout.split())
    for expected in (
        "--rejected-max-per-tenant N",
        "--rejected-max-bytes-per-tenant BYTES",
        "--max-body-bytes BYTES",
        "--read-max-seconds SECONDS",
        "--header-timeout-s SECONDS",
        "--rejected-max-age-days DAYS",
        "--host ADDRESS",
        "--port PORT",
        "--jwt-jwks-url URL",
        "--retention RULES",
    ):
        assert expected in usage, expected
    assert "TENANT]" not in usage.replace("[:TENANTS]", "")


def test_serve_help_has_no_empty_default():
    text = " ".join(run_cli("serve", "--help").stdout.split())
    assert "(default ;" not in text and "default ;" not in text
    assert "(not set by default; env TSDB_API_KEYS)" in text


@pytest.mark.parametrize(
    ("argv", "usage", "meant"),
    [
        (["serve", "--prot", "8668"], "usage: tsdb-service serve ", "--port"),
        (["export", "--out", "x.csv", "--servce", "lawnmower"], "usage: tsdb-service export ", "--service"),
        (["queries", "run", "--ulr", "http://x"], "usage: tsdb-service queries run ", "--url"),
        (
            ["subscribe", "--broker", "http://o:1026", "--use-case", "all", "--notfy-url", "x"],
            "usage: tsdb-service subscribe ",
            "--notify-url",
        ),
    ],
)
def test_a_mistyped_flag_prints_its_subcommand_usage(tmp_path, argv, usage, meant):
    done = run_cli(*argv, cwd=tmp_path)
    assert done.returncode == 2
    assert done.stderr.startswith(usage), done.stderr
    last = done.stderr.strip().splitlines()[-1]
    assert last.startswith(f"tsdb-service {argv[0]}") and "unrecognized arguments" in last, last
    if meant:
        assert f"did you mean {meant}?" in last
    assert list(tmp_path.iterdir()) == []
