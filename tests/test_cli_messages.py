"""The commands' messages read as sentences (issue 36's slips), each checked
through the real command: libpq's follow-up question, a QuantumLeap database
that does not exist, a broker URL that is not HTTP, and the line that says a
new, empty DuckDB database was created.
"""

from __future__ import annotations

import subprocess

import pytest

from tests.support.cli import run_cli
from tests.support.server import ServerProcess, free_port
from tsdb_service.cli.messages import readable

CREATED = "created a new, empty DuckDB database at"


def one_error(done: subprocess.CompletedProcess, status: int = 2) -> str:
    assert done.returncode == status, done.stdout + done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), done.stderr
    return lines[0]


def test_libpq_question_becomes_a_parenthesis():
    joined = (
        'connection to server at "127.0.0.1", port 1 failed: Connection refused\n'
        "\tIs the server running on that host and accepting TCP/IP connections?"
    )
    assert readable(joined) == (
        'connection to server at "127.0.0.1", port 1 failed: Connection refused '
        "(is the server running on that host and accepting TCP/IP connections?)"
    )
    assert readable("no such table") == "no such table"


@pytest.mark.parametrize("command", ["serve", "import"])
def test_a_refused_postgresql_connection_reads_as_a_sentence(command, tmp_path):
    url = f"postgresql://postgres@127.0.0.1:{free_port()}/tsdb"
    args = ["serve", "--db", url, "--port", str(free_port())]
    if command == "import":
        args = ["import", "quantumleap", "--from", url, "--db", str(tmp_path / "t.duckdb")]
    line = one_error(run_cli(*args))
    assert "Connection refused (is the server running on that host" in line, line
    assert "refused Is" not in line


def test_a_quantumleap_database_that_does_not_exist_is_named(pg_cluster, tmp_path):
    base = pg_cluster.url.rsplit("/", 1)[0]
    db = tmp_path / "t.duckdb"
    line = one_error(run_cli("import", "quantumleap", "--from", f"{base}/quantum_leap_typo", "--db", str(db)))
    assert line == (
        f"error: cannot connect to QuantumLeap's database 'quantum_leap_typo' on 127.0.0.1:{pg_cluster.port}: "
        "there is no database of that name. Name an existing one in --from (QuantumLeap's default: quantumleap); "
        f"psql -h 127.0.0.1 -p {pg_cluster.port} -U postgres -l lists them"
    )
    assert not db.exists(), "nothing is created"


@pytest.mark.parametrize(
    ("args", "expected"),
    [
        (
            ["--broker", "mqtt://mosquitto:1883"],
            "error: --broker 'mqtt://mosquitto:1883' is not an http:// or https:// URL: give one like "
            "http://orion:1026 (MQTT goes in --mqtt mqtt://HOST:1883)",
        ),
        (
            ["--broker", "orion:1026"],
            "error: --broker 'orion:1026' is not an http:// or https:// URL: give one like http://orion:1026",
        ),
        (
            ["--broker", "http://orion:1026", "--notify-url", "tsdb-service:8668/v2/notify"],
            "error: --notify-url 'tsdb-service:8668/v2/notify' is not an http:// or https:// URL: give one like "
            "http://tsdb-service:8668/v2/notify",
        ),
    ],
)
def test_subscribe_checks_the_broker_url_before_any_network_call(args, expected):
    """``orion`` does not resolve here: a network call would fail differently (and slowly)."""
    done = run_cli("subscribe", "--use-case", "all", *args, timeout=20)
    assert one_error(done) == expected
    assert done.stdout == "", "nothing was attempted"


def test_serve_says_once_that_it_created_a_new_database(tmp_path):
    path = tmp_path / "new" / "history.duckdb"
    with ServerProcess(path) as first:
        pass
    with ServerProcess(path) as second:
        pass
    assert f"{CREATED} {path}" in first.output()
    assert first.output().count(CREATED) == 1
    assert CREATED not in second.output()


def test_migrate_says_it_created_a_new_database(tmp_path):
    path = tmp_path / "history.duckdb"
    created = run_cli("migrate", "--db", str(path))
    assert created.returncode == 0 and created.stdout.splitlines()[0] == f"{CREATED} {path}", created.stdout
    again = run_cli("migrate", "--db", str(path))
    assert again.returncode == 0 and CREATED not in again.stdout
