"""Debian packages a test needs, installed when missing and we may (root, apt-get)."""

from __future__ import annotations

import os
import shutil
import subprocess

__all__ = ["apt_install"]


def apt_install(*packages: str) -> str | None:
    """``apt-get install`` ``packages``; the reason it could not, or None."""
    names = " / ".join(packages)
    if not hasattr(os, "geteuid") or os.geteuid() != 0:
        return f"{names} not installed and we are not root to apt-get them"
    if shutil.which("apt-get") is None:
        return f"{names} not installed and there is no apt-get"
    env = {**os.environ, "DEBIAN_FRONTEND": "noninteractive"}
    for command in (["apt-get", "update", "-qq"], ["apt-get", "install", "-y", "-qq", *packages]):
        try:
            done = subprocess.run(command, env=env, capture_output=True, text=True, timeout=900)
        except (OSError, subprocess.TimeoutExpired) as exc:
            return f"{' '.join(command)} failed: {exc}"
        if done.returncode != 0:
            return f"{' '.join(command)} failed ({done.returncode}): {(done.stderr or done.stdout)[-500:]}"
    return None
