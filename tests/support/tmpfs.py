"""A small tmpfs for disk-full tests, and a way to fill it.

    with small_tmpfs(tmp_path / "disk", "16m") as disk:
        filler = fill(disk, leave=200_000)   # all but ~200 kB taken
        ...
        filler.unlink()                      # space back

Mounting needs root (and a kernel that lets this process mount); otherwise
``small_tmpfs`` skips the calling test, saying why. The mount is always
undone, lazily if a file on it is still open.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import subprocess
from collections.abc import Iterator
from pathlib import Path

import pytest

__all__ = ["fill", "free_bytes", "small_tmpfs"]


@contextlib.contextmanager
def small_tmpfs(where: Path, size: str, mode: str = "0755") -> Iterator[Path]:
    if os.geteuid() != 0:
        pytest.skip("needs root to mount a small tmpfs (to fill a disk without filling the real one)")
    if shutil.which("mount") is None or shutil.which("umount") is None:
        pytest.skip("mount/umount are not installed")
    where.mkdir(parents=True, exist_ok=True)
    done = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", f"size={size},mode={mode}", "tmpfs", str(where)], capture_output=True, text=True
    )
    if done.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {done.stderr.strip() or done.returncode}")
    try:
        yield where
    finally:
        if subprocess.run(["umount", str(where)], capture_output=True).returncode != 0:
            subprocess.run(["umount", "-l", str(where)], capture_output=True)


def fill(disk: Path, leave: int, name: str = "filler") -> Path:
    """Take all free space on ``disk`` but about ``leave`` bytes; return the
    file holding it (delete it to give the space back)."""
    path = disk / name
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o644)
    chunk = b"\0" * 65536
    try:
        while True:
            try:
                os.write(fd, chunk)
            except OSError:
                break
        with contextlib.suppress(OSError):  # the last few bytes
            while os.write(fd, b"\0" * 4096):
                pass
    finally:
        os.close(fd)
    os.truncate(path, max(0, path.stat().st_size - leave))
    return path


def free_bytes(disk: Path) -> int:
    stat = os.statvfs(disk)
    return stat.f_bavail * stat.f_frsize
