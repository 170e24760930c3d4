"""A private Eclipse Mosquitto broker, for ``demo --via mqtt`` and the tests.

Mosquitto (Debian's ``mosquitto`` package, or any ``mosquitto`` on PATH) on
one port of 127.0.0.1, anonymous, with persistence in its own directory: a
graceful restart keeps every session and the messages queued for it, as a
deployment's broker should (``docs/mqtt.md``).
"""

from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import tempfile
import time
from pathlib import Path

SEARCH = ("/usr/sbin/mosquitto", "/usr/local/sbin/mosquitto", "/opt/homebrew/sbin/mosquitto")


def find_mosquitto() -> str | None:
    """The broker's binary, or None when none is installed."""
    found = shutil.which("mosquitto")
    if found:
        return found
    return next((path for path in SEARCH if os.access(path, os.X_OK)), None)


def free_port(host: str = "127.0.0.1") -> int:
    with socket.socket() as s:
        s.bind((host, 0))
        return s.getsockname()[1]


class LocalMosquitto:
    """``start()``, ``restart()`` (graceful: state saved and reloaded),
    ``kill()`` (SIGKILL), ``stop()``; ``url`` is ``mqtt://127.0.0.1:PORT``."""

    def __init__(self, binary: str | None = None, port: int | None = None, directory: str | os.PathLike | None = None):
        found = binary or find_mosquitto()
        if found is None:
            raise RuntimeError("mosquitto is not installed (Debian: apt-get install mosquitto)")
        self.binary = found
        self.port = port or free_port()
        self._own_dir = directory is None
        self.directory = Path(directory or tempfile.mkdtemp(prefix="tsdb-mosquitto-"))
        self.directory.mkdir(parents=True, exist_ok=True)
        self.config = self.directory / "mosquitto.conf"
        self.log_path = self.directory / "mosquitto.log"
        self.proc: subprocess.Popen | None = None

    @property
    def url(self) -> str:
        return f"mqtt://127.0.0.1:{self.port}"

    def _write_config(self) -> None:
        lines = [
            f"listener {self.port} 127.0.0.1",
            "allow_anonymous true",
            "persistence true",
            f"persistence_location {self.directory}/",
            # Queue for an absent subscriber without the default cap of
            # 1,000 messages (beyond it mosquitto drops QoS 1 messages).
            "max_queued_messages 0",
            f"log_dest file {self.log_path}",
            "log_type error",
            "log_type warning",
            "log_type notice",
        ]
        if os.geteuid() == 0:
            lines.append("user root")  # else it drops to user mosquitto, who cannot write our directory
        self.config.write_text("\n".join(lines) + "\n")

    def start(self, timeout: float = 10.0) -> LocalMosquitto:
        self._write_config()
        self.proc = subprocess.Popen(
            [self.binary, "-c", str(self.config)],
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise RuntimeError(f"mosquitto exited with code {self.proc.returncode}:\n{self.log_tail()}")
            try:
                socket.create_connection(("127.0.0.1", self.port), timeout=0.5).close()
                return self
            except OSError:
                time.sleep(0.02)
        self.kill()
        raise RuntimeError(f"mosquitto did not listen on port {self.port} within {timeout:g} s:\n{self.log_tail()}")

    def stop(self, timeout: float = 10.0) -> None:
        """SIGTERM: mosquitto saves its state (sessions, queued messages) and exits."""
        proc = self.proc
        if proc is None or proc.poll() is not None:
            return
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout)
        except subprocess.TimeoutExpired:
            self.kill()

    def kill(self) -> None:
        proc = self.proc
        if proc is not None and proc.poll() is None:
            proc.kill()
            proc.wait()

    def restart(self) -> LocalMosquitto:
        self.stop()
        return self.start()

    def close(self) -> None:
        """Stop it and delete its directory (if it made it)."""
        self.stop()
        if self._own_dir:
            shutil.rmtree(self.directory, ignore_errors=True)

    def log_tail(self, lines: int = 20) -> str:
        try:
            text = self.log_path.read_text(errors="replace")
        except OSError:
            return "(no log)"
        return "\n".join(text.splitlines()[-lines:]) or "(empty log)"

    def __enter__(self) -> LocalMosquitto:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.close()
