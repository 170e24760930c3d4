"""PostgreSQL helpers shared by the benchmarks.

A private, throwaway cluster (``tests/support/pg_cluster.py``'s ``PgCluster``, test and benchmark
infrastructure, not part of the package:
``initdb`` + ``pg_ctl`` on a temporary directory and a free port, listening on
127.0.0.1 only), plus what the benchmarks read off it: the CPU time and the
memory of its processes, and the size of a database on disk.
"""

from __future__ import annotations

import contextlib
import math
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

try:
    import psutil
except ImportError:  # pragma: no cover - only for the CPU / memory figures
    psutil = None


class BenchCluster:
    """A started ``PgCluster`` and one fresh database on it."""

    def __init__(self, dbname: str = "bench"):
        from tests.support.pg_cluster import PgCluster

        self.cluster = PgCluster()
        self.dbname = dbname
        self.url: str | None = None

    def start(self) -> BenchCluster:
        self.cluster.start()
        try:
            self.url = self.cluster.database(self.dbname)
        except Exception:
            self.cluster.stop()
            raise
        return self

    def stop(self) -> None:
        self.cluster.stop()

    def __enter__(self) -> BenchCluster:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    @property
    def version(self) -> str:
        import psycopg

        with psycopg.connect(self.url) as conn:
            return conn.execute("SHOW server_version").fetchone()[0]

    # --- what the benchmarks measure ------------------------------------------------------

    def _processes(self) -> list:
        if psutil is None:
            return []
        try:
            pid = int((self.cluster.data / "postmaster.pid").read_text().split()[0])
            main = psutil.Process(pid)
            return [main, *main.children(recursive=True)]
        except (OSError, ValueError, IndexError, psutil.Error):
            return []

    def cpu_seconds(self) -> float:
        """User + system CPU of the postmaster and all its backends so far
        (backends that already exited are not counted)."""
        procs = self._processes()
        if not procs:
            return math.nan
        total = 0.0
        for p in procs:
            with contextlib.suppress(psutil.Error):
                total += sum(p.cpu_times()[:2])
        return total

    def memory_bytes(self) -> int | None:
        """Proportional set size (PSS) summed over the cluster's processes:
        shared buffers are counted once, not once per backend."""
        procs = self._processes()
        if not procs:
            return None
        total = 0
        for p in procs:
            try:
                info = p.memory_full_info()
                total += getattr(info, "pss", info.rss)
            except psutil.Error:
                pass
        return total

    def database_bytes(self) -> int:
        import psycopg

        with psycopg.connect(self.url) as conn:
            return int(conn.execute("SELECT pg_database_size(current_database())").fetchone()[0])

    def vacuum_analyze(self) -> None:
        """What a loaded table gets from autovacuum sooner or later, done now
        so that it does not run during the measurement."""
        import psycopg

        with psycopg.connect(self.url, autocommit=True) as conn:
            conn.execute("VACUUM (ANALYZE) samples")
            conn.execute("VACUUM (ANALYZE) series")
            conn.execute("CHECKPOINT")
