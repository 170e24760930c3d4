"""The compactor: moves the hot rows into the table sorted by (series, time),
and the hot rollup rows into their levels (``storage.rollups``)."""

from __future__ import annotations

import logging
import threading
from contextlib import AbstractContextManager

import duckdb

from tsdb_service.core.errors import first_line
from tsdb_service.storage.duckdb.connection import rollback_quietly, scalar
from tsdb_service.storage.duckdb.dialect import DuckDBDialect
from tsdb_service.storage.rollups import HOT, LEVELS, merge

# Hot rollup rows are merged into their levels once there are this many
# (readers combine them meanwhile; a few thousand cost a read nothing).
MERGE_ROWS = 20_000
_DIALECT = DuckDBDialect()

log = logging.getLogger(__name__)


class Compactor:
    """Keeps the sorted table sorted, off the acknowledgement path.

    Moving hot rows is one transaction (insert sorted, delete moved), so a
    reader sees each sample exactly once. Only this thread touches
    ``samples``; the writer only appends to ``samples_hot``; the two never
    conflict. Likewise for rollups: the writer appends to ``rollups_hot``,
    this thread merges those rows into the level tables (``_merge``), one
    transaction at a time; deletes recompute rollups under its lock.
    """

    def __init__(
        self, con: duckdb.DuckDBPyConnection, compact_rows: int, major_runs: int, interval: float = 2.0, on_error=None
    ):
        self._con = con
        self._on_error = on_error  # told about each failure (the store looks for invalidation)
        self._compact_rows = compact_rows
        self._major_runs = major_runs
        self._interval = interval
        self._runs = 0
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, name="tsdb-compactor", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def holding(self) -> AbstractContextManager[bool]:
        """Hold while deleting rows (deletes, retention): no move or rewrite
        runs meanwhile, so its copy cannot resurrect them (``_lock``)."""
        return self._lock

    def stop(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join()

    def _loop(self) -> None:
        cur = self._con.cursor()
        try:
            while not self._stop.wait(self._interval):
                try:
                    hot = scalar(cur, "SELECT count(*) FROM samples_hot")
                    if hot >= self._compact_rows:
                        self._move(cur)
                        if self._runs >= self._major_runs:
                            self._rewrite(cur)
                    if scalar(cur, f"SELECT count(*) FROM {HOT}") >= MERGE_ROWS:
                        self._merge(cur)
                except Exception as exc:  # keep serving; compaction is an optimisation
                    rollback_quietly(cur)
                    if self._on_error is not None and self._on_error(exc) is not None:
                        log.warning("compaction stopped, the database is invalid: %s", first_line(exc))
                        return  # the store's reopen starts a new compactor
                    log.exception("compaction failed; will retry")
        finally:
            cur.close()

    def run_once(self, full: bool) -> None:
        cur = self._con.cursor()
        try:
            self._move(cur)
            if full:
                self._rewrite(cur)
            while self._merge(cur):
                pass
        finally:
            cur.close()

    def _merge(self, cur: duckdb.DuckDBPyConnection) -> int:
        """Hot rollup rows into their levels (``storage.rollups.merge``);
        how many moved."""
        with self._lock:
            cur.execute("BEGIN")
            try:
                moved = merge(_DIALECT, lambda sql, params: cur.execute(sql, params).fetchall(), 4 * MERGE_ROWS)
                cur.execute("COMMIT")
            except Exception:
                rollback_quietly(cur)
                raise
        return moved

    def _move(self, cur: duckdb.DuckDBPyConnection) -> None:
        with self._lock:
            cur.execute("BEGIN")
            try:
                upto = scalar(cur, "SELECT max(rid) FROM samples_hot")
                if upto is None:
                    cur.execute("COMMIT")
                    return
                cur.execute(
                    "INSERT INTO samples SELECT * FROM samples_hot WHERE rid <= ? ORDER BY sid, t, rid",
                    [upto],
                )
                cur.execute("DELETE FROM samples_hot WHERE rid <= ?", [upto])
                cur.execute("COMMIT")
            except Exception:
                rollback_quietly(cur)
                raise
            self._runs += 1

    def _rewrite(self, cur: duckdb.DuckDBPyConnection) -> None:
        with self._lock:
            cur.execute("BEGIN")
            try:
                cur.execute("CREATE TABLE samples_sorted AS SELECT * FROM samples ORDER BY sid, t, rid")
                cur.execute("DROP TABLE samples")
                cur.execute("ALTER TABLE samples_sorted RENAME TO samples")
                for level in LEVELS:  # one series' rollups in few row groups; rows merges replaced dropped
                    cur.execute(
                        f"CREATE TABLE {level.table}_sorted AS SELECT * FROM {level.table} ORDER BY sid, bucket"
                    )
                    cur.execute(f"DROP TABLE {level.table}")
                    cur.execute(f"ALTER TABLE {level.table}_sorted RENAME TO {level.table}")
                cur.execute("COMMIT")
            except Exception:
                rollback_quietly(cur)
                raise
            self._runs = 0
