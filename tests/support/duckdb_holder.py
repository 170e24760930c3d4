"""Another process holding a DuckDB file open, as a running service does.

    with held_duckdb(path) as pid:
        ...   # duckdb.connect(path) elsewhere fails: "Conflicting lock ... (PID pid)"

The holder is a plain Python process with one connection (it listens on no
port); it is killed when the block ends.
"""

from __future__ import annotations

import contextlib
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

_HOLD = "import duckdb, sys, time; c = duckdb.connect(sys.argv[1]); print('held', flush=True); time.sleep(120)"


@contextlib.contextmanager
def held_duckdb(path: Path) -> Iterator[int]:
    holder = subprocess.Popen([sys.executable, "-c", _HOLD, str(path)], stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout is not None and holder.stdout.readline().strip() == "held"
        yield holder.pid
    finally:
        holder.kill()
        holder.wait()
        if holder.stdout is not None:
            holder.stdout.close()
