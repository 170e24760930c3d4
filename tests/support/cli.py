"""Run ``tsdb-service`` as an operator does: ``python -m tsdb_service ARGS`` in
a subprocess, without the ``TSDB_*`` variables of the test run's own
environment (they would change what is being tested)."""

from __future__ import annotations

import os
import subprocess
import sys


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
    """A refused setting: exit status 2 and one ``error: ...`` line holding every needle."""
    assert done.returncode == 2, done.stdout + done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), done.stderr
    for needle in needles:
        assert needle in lines[0], lines[0]
