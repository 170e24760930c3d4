"""Run tsdb-service as a real subprocess, for tests that need one.

    with ServerProcess(tmp_path / "db.duckdb") as server:
        httpx.post(server.url + "/v2/notify", ...)
        server.kill()                      # SIGKILL: a crash
    ServerProcess(same_path).start()       # restart on the same file

``start()`` picks a free port, launches ``python -m tsdb_service serve --db
PATH --host 127.0.0.1 --port N`` and waits for ``GET /health`` to answer 200.
If the server exits or does not become healthy in time it raises
``ServerError`` carrying the server's output. The output goes to a log file
(``.log_path``, ``.output()``), never to a pipe that could fill up.

The environment is the caller's minus any ``TSDB_*`` variable (so a
developer's shell cannot change what a test runs against), plus
``extra_env``. ``args`` are appended to the ``serve`` command line.
"""

from __future__ import annotations

import atexit
import contextlib
import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
import urllib.error
import urllib.request
from collections.abc import Mapping, Sequence
from pathlib import Path

__all__ = ["ServerError", "ServerProcess", "free_port"]

HOST = "127.0.0.1"

# Every server a test started: one still running when the test process
# exits (a failed assertion between start() and kill()) is killed then, so
# no test leaves a service behind on the machine.
_STARTED: list[ServerProcess] = []


@atexit.register
def _kill_leftovers() -> None:
    for server in list(_STARTED):
        if server.running():
            server.kill()


class ServerError(RuntimeError):
    """The server did not start or stop as expected; carries its output."""


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind((HOST, 0))
        return s.getsockname()[1]


class ServerProcess:
    def __init__(
        self,
        db_path: str | os.PathLike[str],
        extra_env: Mapping[str, str] | None = None,
        args: Sequence[str] | None = None,
        *,
        startup_timeout: float = 30.0,
        log_dir: str | os.PathLike[str] | None = None,
    ):
        # A DuckDB file, or a postgresql:// URL (kept verbatim: Path would fold "//").
        self.db = str(db_path)
        self.is_url = "://" in self.db
        self.db_path = Path(tempfile.gettempdir()) / "tsdb-server" if self.is_url else Path(db_path)
        self.extra_env = dict(extra_env or {})
        self.args = list(args or [])
        self.startup_timeout = startup_timeout
        if log_dir is None:
            log_dir = self.db_path if self.is_url else self.db_path.parent
            Path(log_dir).mkdir(parents=True, exist_ok=True)
        self.log_dir = Path(log_dir)
        self.port: int | None = None
        self.proc: subprocess.Popen | None = None
        self.log_path: Path | None = None
        self._log = None

    # -- lifecycle

    @property
    def url(self) -> str:
        if self.port is None:
            raise ServerError("server not started")
        return f"http://{HOST}:{self.port}"

    @property
    def pid(self) -> int | None:
        return self.proc.pid if self.proc else None

    @property
    def returncode(self) -> int | None:
        return self.proc.poll() if self.proc else None

    def running(self) -> bool:
        return self.proc is not None and self.proc.poll() is None

    def command(self, port: int) -> list[str]:
        return [
            sys.executable,
            "-m",
            "tsdb_service",
            "serve",
            "--db",
            self.db,
            "--host",
            HOST,
            "--port",
            str(port),
            *self.args,
        ]

    def environment(self) -> dict[str, str]:
        env = {k: v for k, v in os.environ.items() if not k.startswith("TSDB_")}
        env["PYTHONUNBUFFERED"] = "1"
        env.update(self.extra_env)
        return env

    def start(self) -> ServerProcess:
        if self.running():
            raise ServerError("server already running")
        # A free port can be taken between our probe and the server's bind:
        # retry on a fresh port if the server dies saying so.
        for attempt in range(3):
            self.port = free_port()
            self._spawn()
            try:
                self._wait_healthy()
                return self
            except ServerError:
                output = self.output()
                if self.proc.poll() is not None and "address already in use" in output.lower() and attempt < 2:
                    continue
                self.kill()
                raise
        raise AssertionError("unreachable")

    def _spawn(self) -> None:
        if self not in _STARTED:
            _STARTED.append(self)
        self._close_log()
        self.log_dir.mkdir(parents=True, exist_ok=True)
        fd, name = tempfile.mkstemp(prefix=f"server-{self.db_path.stem}-", suffix=".log", dir=self.log_dir)
        self.log_path = Path(name)
        self._log = os.fdopen(fd, "wb")
        self.proc = subprocess.Popen(
            self.command(self.port),
            stdin=subprocess.DEVNULL,
            stdout=self._log,
            stderr=subprocess.STDOUT,
            env=self.environment(),
            start_new_session=True,  # a ^C in the test run goes to pytest only
        )

    def _wait_healthy(self) -> None:
        deadline = time.monotonic() + self.startup_timeout
        last = "no answer"
        while time.monotonic() < deadline:
            code = self.proc.poll()
            if code is not None:
                raise ServerError(self._describe(f"server exited with code {code} before it was healthy"))
            try:
                with urllib.request.urlopen(self.url + "/health", timeout=2) as resp:
                    if resp.status == 200:
                        return
                    last = f"HTTP {resp.status}"
            except urllib.error.HTTPError as exc:
                last = f"HTTP {exc.code}"
            except OSError as exc:
                last = repr(exc)
            time.sleep(0.05)
        raise ServerError(self._describe(f"server not healthy after {self.startup_timeout:g} s (last: {last})"))

    def children(self) -> list[int]:
        """The server's child processes (``--ingest-processes``: its acceptors)."""
        if self.proc is None or self.proc.poll() is not None:
            return []
        try:
            text = Path(f"/proc/{self.proc.pid}/task/{self.proc.pid}/children").read_text()
        except OSError:
            return []
        return [int(pid) for pid in text.split()]

    def kill(self) -> int | None:
        """SIGKILL (a crash: no drain, no checkpoint) and reap."""
        if self.proc is None:
            return None
        if self.proc.poll() is None:
            try:  # the whole process group: a crash leaves no helper behind
                os.killpg(self.proc.pid, signal.SIGKILL)
            except (ProcessLookupError, PermissionError):
                self.proc.send_signal(signal.SIGKILL)
        code = self.proc.wait()
        self._close_log()
        return code

    def terminate(self, timeout: float = 30.0) -> int:
        """SIGTERM (graceful drain) and wait; SIGKILL and raise on timeout."""
        if self.proc is None:
            raise ServerError("server not started")
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(timeout)
            except subprocess.TimeoutExpired:
                self.kill()
                raise ServerError(self._describe(f"server did not exit within {timeout:g} s of SIGTERM")) from None
        self._close_log()
        return self.proc.returncode

    def __enter__(self) -> ServerProcess:
        return self.start()

    def __exit__(self, *exc_info) -> None:
        if self.running():
            with contextlib.suppress(ServerError):  # already killed; do not mask the test's own exception
                self.terminate()
        self._close_log()

    # -- output

    def _close_log(self) -> None:
        if self._log is not None:
            self._log.close()
            self._log = None

    def output(self) -> str:
        if self.log_path is None:
            return ""
        if self._log is not None:
            self._log.flush()
        try:
            return self.log_path.read_text(errors="replace")
        except OSError:
            return ""

    def _describe(self, what: str, lines: int = 60) -> str:
        tail = self.output().splitlines()[-lines:]
        body = "\n".join(f"  | {line}" for line in tail) if tail else "  | (no output)"
        return f"{what}\ncommand: {' '.join(self.command(self.port))}\nserver output ({self.log_path}):\n{body}"
