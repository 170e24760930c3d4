"""Start ``tsdb-service serve`` as a child process for the demo, and stop it cleanly.

A separate process rather than an in-process server: the service then runs
exactly as in production (its own event loop, its own core next to the
simulators), and stopping it with SIGTERM exercises the graceful drain that
checkpoints the DuckDB file.
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import httpx


class LocalService:
    """The demo's own service on ``db``; its output goes to ``log_path``."""

    def __init__(self, db: str, host: str, port: int, log_path: Path, args: tuple[str, ...] = ()):
        self.db, self.host, self.port, self.log_path = db, host, port, log_path
        self.args = args  # more ``serve`` flags (the demo's MQTT consumer)
        self.proc: subprocess.Popen | None = None

    @property
    def url(self) -> str:
        host = "127.0.0.1" if self.host in ("0.0.0.0", "") else self.host
        return f"http://{host}:{self.port}"

    def start(self, timeout: float = 60.0) -> LocalService:
        self._check_port_free()
        if "://" not in self.db:
            Path(self.db).parent.mkdir(parents=True, exist_ok=True)
        self.log_path.parent.mkdir(parents=True, exist_ok=True)
        command = [
            sys.executable,
            "-m",
            "tsdb_service",
            "serve",
            "--db",
            self.db,
            "--host",
            self.host,
            "--port",
            str(self.port),
            *self.args,
        ]
        with open(self.log_path, "ab") as log:
            # Own session: a Ctrl-C reaches the demo, which drains and then stops us in order.
            self.proc = subprocess.Popen(
                command, stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT, start_new_session=True
            )
        try:
            self._wait_healthy(timeout)
        except BaseException:  # a Ctrl-C while waiting must not orphan the server
            self.stop()
            raise
        return self

    def stop(self, timeout: float = 30.0) -> int | None:
        """SIGTERM (drain and checkpoint), then SIGKILL if it hangs."""
        if self.proc is None or self.proc.poll() is not None:
            return self.proc.returncode if self.proc else None
        self.proc.send_signal(signal.SIGTERM)
        try:
            return self.proc.wait(timeout)
        except subprocess.TimeoutExpired:
            os.killpg(self.proc.pid, signal.SIGKILL)
            return self.proc.wait()

    def wait_consumed(self, count: int, timeout: float = 30.0) -> int:
        """Wait until its MQTT consumer settled ``count`` messages (stored,
        rejected or known redeliveries, by ``/metrics``); how many it had."""
        deadline = time.monotonic() + timeout
        settled = 0
        while True:
            try:
                metrics = httpx.get(self.url + "/metrics", timeout=5.0).text
                settled = sum(
                    int(float(line.rsplit(" ", 1)[1]))
                    for line in metrics.splitlines()
                    if line.startswith("tsdb_mqtt_messages_total{")
                )
            except (httpx.HTTPError, ValueError, IndexError):
                pass
            if settled >= count or time.monotonic() > deadline:
                return settled
            time.sleep(0.1)

    def _check_port_free(self) -> None:
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as probe:
            try:
                probe.bind((self.host, self.port))
            except OSError:
                raise RuntimeError(
                    f"port {self.port} on {self.host} is taken: pick another with --port, "
                    f"or feed the service already running there with --no-serve --url {self.url}"
                ) from None

    def _wait_healthy(self, timeout: float) -> None:
        proc = self.proc
        assert proc is not None, "start() launches the service first"
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if proc.poll() is not None:
                raise RuntimeError(f"the service exited with code {proc.returncode}:\n{self.log_tail()}")
            try:
                health = httpx.get(self.url + "/health", timeout=2.0)
                # "warn" while its MQTT consumer subscribes: what is published before is not kept for it
                if health.status_code == 200 and health.json().get("status") == "pass":
                    return
            except (httpx.HTTPError, ValueError):
                pass
            time.sleep(0.1)
        raise RuntimeError(f"the service was not healthy after {timeout:g} s:\n{self.log_tail()}")

    def log_tail(self, lines: int = 30) -> str:
        try:
            text = self.log_path.read_text(errors="replace")
        except OSError:
            return "(no output)"
        return "\n".join(f"  | {line}" for line in text.splitlines()[-lines:]) or "(no output)"
