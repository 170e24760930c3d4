"""Opening the DuckDB file, migrating it, and knowing when DuckDB gave up on it.

A full disk can make DuckDB invalidate the database: when the automatic
checkpoint after a commit cannot write the file, the commit is durable (it is
in the WAL) but every later call fails until the file is reopened
(``fatal_kind`` tells which case an error is). ``Gate`` lets many threads use
the connection at once, or one reopen alone.
"""

from __future__ import annotations

import contextlib
import os
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import duckdb

from tsdb_service.core.errors import Unavailable
from tsdb_service.storage.duckdb.dialect import DuckDBDialect
from tsdb_service.storage.migrations import applied_versions, load_migrations, split_statements
from tsdb_service.storage.rollups import fill_statements
from tsdb_service.storage.sql.dialect import quote_ident

SAMPLE_TABLES = ("samples", "samples_hot")
LOG_SUFFIX = ".ingest-log"  # the ingest log's directory, next to the file (``write.log``)


# After the database is invalidated: first reopen attempt, then doubling to at most.
REOPEN_DELAY_S = 0.5


REOPEN_MAX_DELAY_S = 10.0


# How DuckDB says it gave up on the database instance (duckdb.FatalException).
_INVALIDATED = "database has been invalidated"


_COMMITTED_ANYWAY = "COMMIT succeeded"


NOTHING_STORED = "the database is being reopened after a storage failure (disk full?); nothing was stored, retry later"


MAYBE_STORED = "the database failed while committing (disk full?); this write may or may not have been stored"


def fatal_kind(exc: BaseException) -> str | None:
    """What a DuckDB error says about the database instance:

    ``"refused"``: it was already invalidated, the call did nothing;
    ``"committed"``: the transaction is durable, the checkpoint after it failed
    and the instance is now invalid;
    ``"unknown"``: some other fatal error, the instance is invalid and the
    call's outcome unknown;
    None: an ordinary error, the instance is fine.

    The "invalidated" message quotes the original error (often the
    "COMMIT succeeded" one), so it is tested first.
    """
    text = str(exc)
    if _INVALIDATED in text:
        return "refused"
    if not isinstance(exc, duckdb.FatalException):
        return None
    return "committed" if _COMMITTED_ANYWAY in text else "unknown"


def is_storage_error(exc: BaseException) -> bool:
    """A failure to write the file (full disk, I/O error): the database
    refuses writes until the cause goes away."""
    text = str(exc)
    return isinstance(exc, duckdb.IOException) or "No space left" in text or "Could not write" in text


def migrate_duckdb(con: duckdb.DuckDBPyConnection) -> list[int]:
    """Apply pending migrations; return the versions applied now."""
    done = applied_versions(con)
    applied = []
    for migration in load_migrations("duckdb"):
        if migration.version in done:
            continue
        con.execute("BEGIN")
        try:
            for statement in split_statements(migration.sql):
                con.execute(statement)
            for statement in fill_statements(DuckDBDialect(), migration.version):
                con.execute(statement)
            con.execute(
                "INSERT INTO schema_migrations (version, name) VALUES (?, ?)",
                [migration.version, migration.name],
            )
            con.execute("COMMIT")
        except Exception:
            con.execute("ROLLBACK")
            raise
        applied.append(migration.version)
    return applied


def connect(path: str, read_only: bool = False, checkpoint_bytes: int | None = None) -> duckdb.DuckDBPyConnection:
    if path != ":memory:":
        Path(path).parent.mkdir(parents=True, exist_ok=True)
    try:
        con = duckdb.connect(path, read_only=read_only)
    except duckdb.IOException as exc:
        if "lock" in str(exc).lower():
            raise RuntimeError(
                f"{path} is open in another process. DuckDB allows one process per file: "
                "stop the other tsdb-service, or use PostgreSQL (--db postgresql://...) "
                "to run several."
            ) from exc
        raise
    if checkpoint_bytes is not None and not read_only:
        # Set on the database instance, not as a connect() option: DuckDB
        # refuses a second in-process connection to a file opened with a
        # different configuration, and a plain connect() (migrate, probes,
        # read-only checks) shares the instance and its setting instead.
        # An int, formatted: SET takes no bound parameters.
        con.execute(f"SET GLOBAL wal_autocheckpoint = '{int(checkpoint_bytes)}B'")
    return con


class Gate:
    """Many users of the database connection at once, or one reopen alone.

    Closing a DuckDB connection while another thread runs a query on one of
    its cursors is not safe, so readers and writers hold the gate while they
    use a cursor and the reopen waits for them to leave. Nobody waits to
    enter: while a reopen runs, entering raises ``Unavailable``.
    """

    def __init__(self) -> None:
        self._cond = threading.Condition()
        self._users = 0
        self._shut = False

    @contextlib.contextmanager
    def use(self, refusal: str) -> Iterator[None]:
        with self._cond:
            if self._shut:
                raise Unavailable(refusal)
            self._users += 1
        try:
            yield
        finally:
            with self._cond:
                self._users -= 1
                if self._users == 0:
                    self._cond.notify_all()

    @contextlib.contextmanager
    def alone(self) -> Iterator[None]:
        with self._cond:
            self._shut = True
            self._cond.wait_for(lambda: self._users == 0)
        try:
            yield
        finally:
            with self._cond:
                self._shut = False


def tables_max(cur: duckdb.DuckDBPyConnection, column: str) -> int:
    """The largest ``column`` over both sample tables, each asked alone:
    DuckDB answers a base table's max from its row groups' statistics
    (reading only the row groups that can hold it), but the max over the
    ``samples_all`` view reads the whole column, and the blocks it read
    stayed in memory: about 160 MiB more RSS at start-up with 100M samples."""
    return max(
        (scalar(cur, f"SELECT max({quote_ident(column)}) FROM {quote_ident(table)}") or 0) for table in SAMPLE_TABLES
    )


def scalar(cur: duckdb.DuckDBPyConnection, sql: str) -> Any:
    """The one value of an aggregate query.

    Read with ``fetchall``: after ``fetchone`` the result is still open and
    keeps the cursor in a transaction, and while any transaction is open
    DuckDB skips the automatic checkpoint of every commit. The compactor's
    cursor polls with this between its sleeps, so the write-ahead log (and
    the memory holding what it has not checkpointed) grew without bound
    under a steady load of big batches (``tests/test_wal_growth.py``)."""
    rows = cur.execute(sql).fetchall()
    return rows[0][0] if rows else None


def rollback_quietly(cur: duckdb.DuckDBPyConnection) -> None:
    with contextlib.suppress(duckdb.Error):
        cur.execute("ROLLBACK")


def file_bytes(path: str) -> int:
    try:
        return os.stat(path).st_size
    except FileNotFoundError:
        return 0
