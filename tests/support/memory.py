"""A process's peak resident memory, sampled from outside.

``ru_maxrss`` (``os.wait4``) is no good for a child of a large process: it
counts what the child shared with its parent between ``fork`` and ``exec``,
so under pytest-xdist a small command reads as large as the test worker.
``/proc``'s figures, sampled while the process runs, are the process's own.
"""

from __future__ import annotations

import time

import psutil

__all__ = ["peak_rss_mib"]


def peak_rss_mib(pid: int, until: float | None = None, every: float = 0.02) -> int:
    """The largest resident size of process ``pid`` seen until the
    monotonic time ``until`` (None: until it exits), in MiB."""
    proc = psutil.Process(pid)
    peak = 0
    while until is None or time.monotonic() < until:
        try:
            if proc.status() == psutil.STATUS_ZOMBIE:
                break
            peak = max(peak, proc.memory_info().rss)
        except psutil.NoSuchProcess:
            break
        time.sleep(every)
    return peak // (1024 * 1024)
