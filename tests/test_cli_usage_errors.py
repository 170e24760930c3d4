"""A command-line mistake is three lines and exit status 2: one usage line,
the error, and what was meant when it is close (``did you mean --port?``).

Before, ``serve --prot 80`` printed ``serve``'s whole usage (57 lines, one
per group of flags) above the error, and a mistyped command named none.
Each case runs the real command.
"""

from __future__ import annotations

import pytest

from tests.support.cli import run_cli
from tsdb_service.cli.main import main


def usage_error(*args: str) -> list[str]:
    done = run_cli(*args)
    assert done.returncode == 2, done.stdout + done.stderr
    assert done.stdout == ""
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 2 and lines[0].startswith("usage: "), done.stderr
    return lines


@pytest.mark.parametrize(
    ("args", "usage", "error"),
    [
        (
            ["serve", "--prot", "80"],
            "usage: tsdb-service serve [options]",
            "tsdb-service serve: error: unrecognized arguments: --prot 80 (did you mean --port?)",
        ),
        (
            ["serve", "--max-bdoy-bytes=10"],
            "usage: tsdb-service serve [options]",
            "tsdb-service serve: error: unrecognized arguments: --max-bdoy-bytes=10 (did you mean --max-body-bytes?)",
        ),
        (
            ["sevre"],
            "usage: tsdb-service [-h] [--version] COMMAND ...",
            "tsdb-service: error: unknown command 'sevre' (did you mean serve?)",
        ),
        (
            ["queries", "rn"],
            "usage: tsdb-service queries [-h] {run,build} ...",
            "tsdb-service queries: error: unknown command 'rn' (did you mean run?)",
        ),
        (
            ["import", "qantumleap"],
            "usage: tsdb-service import [-h] SOURCE ...",
            "tsdb-service import: error: unknown command 'qantumleap' (did you mean quantumleap?)",
        ),
        (
            ["export", "--ot", "x.csv"],
            "usage: tsdb-service export --out FILE [options]",
            "tsdb-service export: error: the following arguments are required: --out (--ot: did you mean --out?)",
        ),
        (
            ["export", "--out", "x.csv", "--format", "cvs"],
            "usage: tsdb-service export --out FILE [options]",
            "tsdb-service export: error: argument --format: invalid choice 'cvs' (did you mean csv?)",
        ),
        (
            ["serve", "--port"],
            "usage: tsdb-service serve [options]",
            "tsdb-service serve: error: argument --port: expected one argument",
        ),
    ],
)
def test_one_usage_line_the_error_and_the_hint(args, usage, error):
    assert usage_error(*args) == [usage, error]


def test_an_unknown_command_with_nothing_close_lists_the_commands():
    _, error = usage_error("xyzzy")
    assert error.startswith("tsdb-service: error: unknown command 'xyzzy': choose from serve, migrate, compact")


def test_help_opens_with_the_same_short_usage():
    done = run_cli("import", "quantumleap", "--help")
    assert done.returncode == 0
    assert done.stdout.splitlines()[0] == "usage: tsdb-service import quantumleap --from URL [options]"


@pytest.mark.parametrize(
    ("args", "error"),
    [
        (
            ["import", "quantumleap", "--from", "postgresql://h/ql", "--batch-samples", "abc"],
            "argument --batch-samples: 'abc' is not a whole number: give 1 or more",
        ),
        (
            ["import", "quantumleap", "--from", "postgresql://h/ql", "--batch-samples", "0"],
            "argument --batch-samples: 0 is too small: give 1 or more",
        ),
        (
            ["copy", "--from", "a.duckdb", "--to", "b.duckdb", "--batch-rows", "1e3"],
            "argument --batch-rows: '1e3' is not a whole number: give 1 or more",
        ),
        (["demo", "--speedup", "fast"], "argument --speedup: 'fast' is not a number: give one above 0, e.g. 2 or 0.5"),
        (["demo", "--duration", "inf"], "argument --duration: 'inf': give a finite number above 0, e.g. 2 or 0.5"),
        (["demo", "--concurrency", "many"], "argument --concurrency: 'many' is not a whole number: give 1 or more"),
        (["demo", "--seed", "x"], "argument --seed: 'x' is not a whole number, e.g. 42"),
        (["demo", "--port", "http"], "argument --port: 'http' is not a port: give 1-65535"),
    ],
)
def test_a_bad_value_is_named_not_the_function_that_parses_it(args, error, capsys):
    """``invalid _positive_int value: 'abc'`` named a function of ours. In
    process: the parser is the same, and this runs before any command."""
    with pytest.raises(SystemExit) as exit_:
        main(list(args))
    lines = capsys.readouterr().err.strip().splitlines()
    assert exit_.value.code == 2 and len(lines) == 2, lines
    assert lines[1].endswith(f"error: {error}"), lines
