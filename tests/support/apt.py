"""Debian packages a test needs, installed when missing and we may (root, apt-get).

Several pytest workers may ask at once (the MQTT tests for mosquitto, the
explorer's for chromium): one install runs at a time, behind a file lock
shared by every process on the machine, and apt-get itself waits for dpkg's
lock rather than failing when another apt-get (ours or the system's) holds it.
"""

from __future__ import annotations

import fcntl
import os
import shutil
import subprocess
import tempfile
from pathlib import Path

__all__ = ["apt_install"]

_LOCK = Path(tempfile.gettempdir()) / "tsdb-service-tests-apt.lock"
_WAIT_FOR_DPKG = ["-o", "DPkg::Lock::Timeout=600"]


def apt_install(*packages: str) -> str | None:
    """``apt-get install`` ``packages``; the reason it could not, or None."""
    names = " / ".join(packages)
    if not hasattr(os, "geteuid") or os.geteuid() != 0:
        return f"{names} not installed and we are not root to apt-get them"
    if shutil.which("apt-get") is None:
        return f"{names} not installed and there is no apt-get"
    with _LOCK.open("a") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        try:
            return _install(packages)
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)


def _install(packages: tuple[str, ...]) -> str | None:
    env = {**os.environ, "DEBIAN_FRONTEND": "noninteractive"}
    if _installed(packages, env):  # another worker installed them while we waited
        return None
    for command in (
        ["apt-get", *_WAIT_FOR_DPKG, "update", "-qq"],
        ["apt-get", *_WAIT_FOR_DPKG, "install", "-y", "-qq", *packages],
    ):
        try:
            done = subprocess.run(command, env=env, capture_output=True, text=True, timeout=900)
        except (OSError, subprocess.TimeoutExpired) as exc:
            return f"{' '.join(command)} failed: {exc}"
        if done.returncode != 0:
            return f"{' '.join(command)} failed ({done.returncode}): {(done.stderr or done.stdout)[-500:]}"
    return None


def _installed(packages: tuple[str, ...], env: dict[str, str]) -> bool:
    query = ["dpkg-query", "-W", "-f=${Status}\\n", *packages]
    done = subprocess.run(query, env=env, capture_output=True, text=True, check=False)
    lines = done.stdout.splitlines()
    return done.returncode == 0 and len(lines) == len(packages) and all(s.endswith(" installed") for s in lines)
