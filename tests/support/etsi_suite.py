"""The ETSI NGSI-LD conformance suite's temporal cases, run offline against a service.

The suite, its @context documents and the offline harness are vendored in
``tests/vendor/ngsi-ld-conformance`` (its README says what, from which
upstream commit, and what was left out). Robot Framework and the suite's
libraries come from the project's test extras (``pyproject.toml``), so the
run uses this interpreter, nothing installed by hand.

A run:

1. serves the vendored @context documents on 127.0.0.1 at a free port
   (the harness's ``ctxserver``, a subprocess ended by its own handle);
2. copies the suite to ``OUT/run/work`` with every @context URL that has a
   local copy rewritten to that server (the harness's ``prepare_run``);
3. runs Robot Framework on the main set's files, less the ids of
   ``drop`` (the harness's ``etsi_harness``: per-test timeout, id filter,
   loopback-only HTTP guard, request log);
4. summarizes ``output.xml`` (the harness's ``summarize``): the last line is
   ``etsi temporal: PASSED/TOTAL (failed F, skipped S)``.

The service must reach @contexts on 127.0.0.1 (``TSDB_LD_CONTEXT_ALLOW``)
and start from an empty database (a few cases use fixed entity ids).

Alone, against a service already running on a fresh database::

    .venv/bin/python -m tests.support.etsi_suite http://127.0.0.1:8668 --out /tmp/etsi
"""

from __future__ import annotations

import argparse
import csv
import os
import re
import shutil
import subprocess
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

VENDOR = Path(__file__).resolve().parents[1] / "vendor" / "ngsi-ld-conformance"
HARNESS = VENDOR / "harness"
SETS = HARNESS / "sets"
KNOWN_DEFECTIVE = SETS / "known_defective.ids"
DISPUTED = SETS / "disputed.ids"
HTTPCTRL = VENDOR / "suite" / "libraries" / "robotframework-httpctrl" / "src"
CASES = 146  # the main set (186) less 13 known-defective and 27 disputed ids
FLOOR = 139  # at least 95 % (issue 28; kept by issue 40)
LABEL = "etsi temporal"
_LINE = re.compile(rf"{LABEL}: (\d+)/(\d+) \(failed (\d+), skipped (\d+)\)")


@dataclass
class SuiteRun:
    """What one run of the suite gave: the counts of its last line, where
    its results are (``out``: Robot's log.html, results.tsv,
    requests.tsv...), and every case that did not pass, with why."""

    passed: int
    total: int
    failed: int
    skipped: int
    line: str
    returncode: int
    out: Path
    failures: list[str] = field(default_factory=list)
    seconds: float = 0.0


def run(
    service_url: str,
    out: Path,
    *,
    drop: Sequence[Path] = (KNOWN_DEFECTIVE, DISPUTED),
    min_ratio: float = FLOOR / CASES,
    total_timeout: float = 240,
    test_timeout: str = "60s",
    keep_work: bool = False,
    robot_args: Sequence[str] = (),
) -> SuiteRun:
    """Run the main set's temporal cases (less the ids listed in ``drop``)
    against ``service_url`` (its base URL; ``/ngsi-ld/v1`` is appended)."""
    started = time.monotonic()
    out = out.resolve()
    work = out / "run"
    shutil.rmtree(work, ignore_errors=True)
    work.mkdir(parents=True)
    for name in ("progress.tsv", "requests.tsv"):
        (out / name).write_text("")
    drop_file = out / "drop.ids"
    drop_file.write_text("".join(path.read_text() + "\n" for path in drop))
    api = service_url.rstrip("/")
    api = api if api.endswith("/ngsi-ld/v1") else f"{api}/ngsi-ld/v1"
    contexts = _ContextServer(work / "contexts", out / "ctxserver.log")
    try:
        port = contexts.start()
        _python(
            HARNESS / "prepare_run.py", VENDOR / "suite", VENDOR / "contexts", work, str(port), log=out / "prepare.log"
        )
        context_url = (
            f"http://127.0.0.1:{port}/raw.githubusercontent.com/marek-mraz/ngsi-ld-test-suite/main/"
            "resources/jsonld-contexts/ngsi-ld-test-suite-compound.jsonld"
        )
        code = _robot(api, context_url, work / "work", out, drop_file, test_timeout, total_timeout, robot_args)
    finally:
        contexts.stop()
        if not keep_work:
            shutil.rmtree(work / "work", ignore_errors=True)
            shutil.rmtree(work / "contexts", ignore_errors=True)
    summary = subprocess.run(
        [
            sys.executable,
            str(HARNESS / "summarize.py"),
            str(out / "output.xml"),
            str(out),
            str(SETS / "temporal_only.ids"),
            f"{min_ratio:.6f}",
            LABEL,
            str(out / "selected.txt"),
            str(out / "progress.tsv"),
        ],
        capture_output=True,
        text=True,
        check=False,
    )
    (out / "summary.txt").write_text(summary.stdout + summary.stderr)
    lines = summary.stdout.strip().splitlines()
    last = lines[-1] if lines else f"{LABEL}: 0/0 (failed 0, skipped 0)"
    found = _LINE.match(last)
    counts = tuple(int(g) for g in found.groups()) if found else (0, 0, 0, 0)
    return SuiteRun(
        *counts,
        line=last if found else f"{last} (robot exit {code}; see {out}/robot-console.log)",
        returncode=summary.returncode,
        out=out,
        failures=_failures(out / "results.tsv"),
        seconds=time.monotonic() - started,
    )


def _robot(
    api: str,
    context_url: str,
    work: Path,
    out: Path,
    drop_file: Path,
    test_timeout: str,
    total_timeout: float,
    robot_args: Sequence[str],
) -> int:
    files = (SETS / "main.files").read_text().split()
    env = {
        **{k: v for k, v in os.environ.items() if not k.startswith(("ETSI_", "TSDB_"))},
        "ETSI_TEST_TIMEOUT": test_timeout,
        "ETSI_HTTP_TIMEOUT": "20",
        "ETSI_KEEP_IDS": "",
        "ETSI_DROP_IDS": str(drop_file),
        "ETSI_REQ_LOG": str(out / "requests.tsv"),
        "ETSI_SELECTED": str(out / "selected.txt"),
        "ETSI_PROGRESS": str(out / "progress.tsv"),
        "NO_PROXY": "127.0.0.1,localhost",
        "PYTHONDONTWRITEBYTECODE": "1",  # no __pycache__ in the vendored harness
    }
    variables = {
        "url": api,
        "temporal_api_url": api,
        "ngsild_test_suite_context": context_url,
        "notification_server_host": "127.0.0.1",
        "notification_server_port": "18997",
        "context_source_host": "127.0.0.1",
        "context_source_port": "18998",
        "context_server_host": "127.0.0.1",
        "context_server_port": "18999",
        "mqtt_broker_host": "127.0.0.1",
    }
    command = [
        sys.executable,
        "-m",
        "robot",
        "--pythonpath",
        str(HARNESS),
        "--pythonpath",
        str(HTTPCTRL),
        "--prerunmodifier",
        "etsi_harness.Prepare",
        "--listener",
        "etsi_harness.HttpGuard",
        *[arg for name, value in variables.items() for arg in ("--variable", f"{name}:{value}")],
        "--name",
        "ETSI NGSI-LD temporal",
        "--outputdir",
        str(out),
        "--output",
        "output.xml",
        "--log",
        "log.html",
        "--report",
        "report.html",
        "--console",
        "verbose",
        "--consolewidth",
        "150",
        *robot_args,
        *files,
    ]
    with (out / "robot-console.log").open("w") as console:
        proc = subprocess.Popen(command, cwd=work, env=env, stdout=console, stderr=subprocess.STDOUT)
        try:
            return proc.wait(timeout=total_timeout)
        except subprocess.TimeoutExpired:
            proc.terminate()  # Robot stops gracefully: unfinished cases fail
            try:
                return proc.wait(timeout=60)
            except subprocess.TimeoutExpired:
                proc.kill()
                return proc.wait()


class _ContextServer:
    """The harness's ``ctxserver`` on a free port, serving ``root``."""

    def __init__(self, root: Path, log: Path):
        self.root = root
        self.log = log
        self.proc: subprocess.Popen | None = None

    def start(self) -> int:
        port_file = self.root.parent / "ctx.port"
        with self.log.open("w") as log:
            self.proc = subprocess.Popen(
                [sys.executable, str(HARNESS / "ctxserver.py"), str(self.root), str(port_file), "0", "0"],
                stdout=log,
                stderr=subprocess.STDOUT,
            )
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline:
            if port_file.is_file() and port_file.read_text().strip():
                return int(port_file.read_text())
            if self.proc.poll() is not None:
                break
            time.sleep(0.05)
        raise RuntimeError(f"the @context server did not start: {self.log.read_text()[-500:]}")

    def stop(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(timeout=5)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()


def _python(script: Path, *args: object, log: Path) -> None:
    with log.open("w") as output:
        subprocess.run(
            [sys.executable, str(script), *map(str, args)], stdout=output, stderr=subprocess.STDOUT, check=True
        )


def _failures(results: Path) -> list[str]:
    if not results.is_file():
        return ["(no results.tsv)"]
    with results.open(newline="") as f:
        rows = list(csv.DictReader(f, delimiter="\t"))
    return [f"{row['test_id']}: {row['message'][:300]}" for row in rows if row["status"] != "PASS"]


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m tests.support.etsi_suite",
        description="Run the ETSI NGSI-LD suite's temporal cases against a running service (start it on an "
        "empty database, with TSDB_LD_CONTEXT_ALLOW=http://127.0.0.1:).",
    )
    parser.add_argument("url", help="the service's base URL, e.g. http://127.0.0.1:8668")
    parser.add_argument("--out", default="etsi-results", help="results folder (default ./etsi-results)")
    parser.add_argument("--all", action="store_true", help="also run the known-defective and disputed cases")
    parser.add_argument("--keep-work", action="store_true", help="keep the rewritten suite copy (OUT/run/work)")
    args, robot_args = parser.parse_known_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    result = run(args.url, out, drop=() if args.all else (KNOWN_DEFECTIVE, DISPUTED), keep_work=args.keep_work,
                 min_ratio=0.0 if args.all else FLOOR / CASES, total_timeout=1800, robot_args=robot_args)  # fmt: skip
    print("\n".join(result.failures))
    print(f"results: {result.out}")
    print(result.line)
    return result.returncode


if __name__ == "__main__":
    sys.exit(main())
