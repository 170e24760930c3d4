"""Consistent copies of a DuckDB store, and restoring one.

A backup is DuckDB's own copy of the whole database (``ATTACH`` a new file,
``COPY FROM DATABASE``) inside one read transaction, which also counts
every table and picks a sample of rows: so the copy, the counts and the
sample are one moment of the store, whatever the writers commit meanwhile.
The store first applies everything its ingest log acknowledged
(``DuckDBStore.backup``), and the copy carries the log position with its
rows (``store_state``): nothing acknowledged before the backup is missing,
and a restore replays nothing.

The copy is written under a temporary name beside the target, read back
(row counts, and the sampled rows value by value), made durable and only
then renamed into place: a target name always holds a whole, verified copy.

A restore copies a backup file to a new place (never over anything that
exists: a live store's file, its WAL or its ingest log), gives the copy a
new database id (so no ingest log of the original is ever replayed into
it), and reads it back the same way.
"""

from __future__ import annotations

import contextlib
import math
import os
import shutil
import time
import uuid
from collections.abc import Iterator, Sequence
from pathlib import Path

import duckdb

from tsdb_service.core.backup import BackupNotVerified, BackupRefused, BackupReport, TableCount
from tsdb_service.core.errors import Unavailable
from tsdb_service.storage.duckdb.connection import LOG_SUFFIX
from tsdb_service.storage.duckdb.state import NEW_IDENTITY_SQL, load_state
from tsdb_service.storage.sql.dialect import quote_ident
from tsdb_service.write.log import fsync_path

SAMPLE_ROWS = 100  # rows per sampled table compared value by value
# The tables sampled, by the columns that find a sampled row again.
SAMPLED: dict[str, tuple[str, ...]] = {
    "samples_all": ("rid", "sid"),
    "series": ("sid",),
    "rejected_notifications": ("id",),
}


Rows = dict[str, list[tuple]]


def take_backup(cur: duckdb.DuckDBPyConnection, target: Path) -> BackupReport:
    """Copy the database ``cur`` is on into the new file ``target`` and
    check the copy; ``BackupRefused`` if ``target`` exists."""
    started = time.monotonic()
    _refuse_existing(target, "the backup's target")
    if not target.parent.is_dir() or not os.access(target.parent, os.W_OK | os.X_OK):
        raise BackupRefused(f"the backup's directory {target.parent} does not exist or is not writable")
    with _partial(target, "backup") as partial:
        counts, sampled, database_id, log_seq = _copy(cur, partial)
        report = _checked(partial, counts, sampled, database_id, log_seq, target, started)
        _install(partial, target, report)
    return report


def restore_backup(backup: Path, target: Path) -> BackupReport:
    """Copy ``backup`` to the new file ``target`` with a new database id,
    and check it against the backup."""
    started = time.monotonic()
    for taken in (target, Path(str(target) + ".wal"), Path(str(target) + LOG_SUFFIX)):
        _refuse_existing(taken, "the restore's target")
    if not backup.is_file():
        raise BackupRefused(f"{backup} is not a file")
    source = _open_backup(backup)
    try:
        counts, sampled = _moment(source)
    finally:
        source.close()
    target.parent.mkdir(parents=True, exist_ok=True)
    with _partial(target, "restore") as partial:
        shutil.copyfile(backup, partial)
        con = duckdb.connect(str(partial))
        try:
            state = None
            if _has_table(con, "store_state"):  # a backup of a store from before migration 0013 has none yet
                con.execute(NEW_IDENTITY_SQL)
                state = load_state(con)
            con.execute("CHECKPOINT")
        finally:
            con.close()
        database_id = str(state.database_id) if state else "(given at the first start)"
        log_seq = state.position.seq if state else 0
        report = _checked(partial, counts, sampled, database_id, log_seq, target, started)
        _install(partial, target, report)
    return report


@contextlib.contextmanager
def _partial(target: Path, what: str) -> Iterator[Path]:
    """The temporary name a copy is made under, removed unless the copy
    got its own; a file system error is a 503 (nothing was kept)."""
    partial = target.with_name(target.name + ".partial")
    _remove(partial)
    try:
        yield partial
    except (OSError, duckdb.IOException) as exc:
        raise Unavailable(f"the {what} could not be written ({exc}); nothing was kept") from exc
    finally:
        _remove(partial)


# -- the copy ----------------------------------------------------------------------------


def _copy(cur: duckdb.DuckDBPyConnection, partial: Path) -> tuple[dict[str, int], Rows, str, int]:
    """One transaction: the copy, every table's count, the sampled rows, the log position."""
    [(source,)] = cur.execute("SELECT current_database()").fetchall()
    alias = quote_ident(f"tsdb_backup_{uuid.uuid4().hex[:12]}")
    cur.execute(f"ATTACH ? AS {alias}", [str(partial)])
    try:
        cur.execute("BEGIN")
        try:
            cur.execute(f"COPY FROM DATABASE {quote_ident(source)} TO {alias}")
            counts, sampled = _moment(cur)
            state = load_state(cur)
            cur.execute("COMMIT")
        except BaseException:
            with contextlib.suppress(duckdb.Error):
                cur.execute("ROLLBACK")
            raise
    finally:
        cur.execute(f"DETACH {alias}")
    return counts, sampled, str(state.database_id), state.position.seq


def _moment(cur: duckdb.DuckDBPyConnection) -> tuple[dict[str, int], Rows]:
    """Every table's row count, and the rows of a sample of each sampled table."""
    tables = [
        name
        for (name,) in cur.execute(
            "SELECT table_name FROM duckdb_tables() WHERE database_name = current_database() "
            "AND schema_name = 'main' AND NOT internal ORDER BY table_name"
        ).fetchall()
    ]
    counts = {t: int(cur.execute(f"SELECT count(*) FROM {quote_ident(t)}").fetchall()[0][0]) for t in tables}
    sampled: Rows = {}
    for table, keys in SAMPLED.items():
        if table != "samples_all" and table not in counts:
            continue
        columns = ", ".join(quote_ident(k) for k in keys)
        picked = cur.execute(
            f"SELECT {columns} FROM {quote_ident(table)} USING SAMPLE reservoir({SAMPLE_ROWS} ROWS) REPEATABLE (37)"
        ).fetchall()
        sampled[table] = _rows_with(cur, table, keys, sorted(set(picked)))
    return counts, sampled


def _rows_with(cur: duckdb.DuckDBPyConnection, table: str, keys: Sequence[str], picked: list[tuple]) -> list[tuple]:
    """Every row of ``table`` whose ``keys`` are among ``picked``, in one order."""
    if not picked:
        return []
    lists = ", ".join(f"unnest(?::BIGINT[]) AS k{i}" for i in range(len(keys)))
    on = " AND ".join(f"t.{quote_ident(k)} = p.k{i}" for i, k in enumerate(keys))
    params = [[row[i] for row in picked] for i in range(len(keys))]
    return cur.execute(
        f"SELECT t.* FROM {quote_ident(table)} t SEMI JOIN (SELECT {lists}) p ON {on} ORDER BY ALL", params
    ).fetchall()


# -- reading the copy back ----------------------------------------------------------------


def _checked(
    partial: Path,
    counts: dict[str, int],
    sampled: Rows,
    database_id: str,
    log_seq: int,
    target: Path,
    started: float,
) -> BackupReport:
    """The copy's counts and sampled rows against the source's; durable."""
    con = duckdb.connect(str(partial), read_only=True)
    try:
        copy_counts, _ = _moment(con)
        mismatched = sum(
            _differing(rows, _rows_with(con, table, SAMPLED[table], _keys(rows, table, con)))
            for table, rows in sampled.items()
        )
    finally:
        con.close()
    fsync_path(partial)
    tables = tuple(
        TableCount(name, counts.get(name, -1), copy_counts.get(name, -1)) for name in sorted({*counts, *copy_counts})
    )
    return BackupReport(
        str(target),
        partial.stat().st_size,
        time.monotonic() - started,
        database_id,
        log_seq,
        tables,
        sum(len(rows) for rows in sampled.values()),
        mismatched,
    )


def _keys(rows: list[tuple], table: str, con: duckdb.DuckDBPyConnection) -> list[tuple]:
    """The key values of ``rows`` (whole rows of ``table``)."""
    names = [d[0] for d in con.execute(f"SELECT * FROM {quote_ident(table)} LIMIT 0").description]
    at = [names.index(k) for k in SAMPLED[table]]
    return sorted({tuple(row[i] for i in at) for row in rows})


def _differing(expected: list[tuple], found: list[tuple]) -> int:
    """Rows of ``expected`` the copy lacks or holds otherwise (NaN equals NaN)."""
    if len(found) != len(expected):
        return max(len(expected) - sum(_same(a, b) for a, b in zip(expected, found, strict=False)), 1)
    return sum(not _same(a, b) for a, b in zip(expected, found, strict=True))


def _same(a: tuple, b: tuple) -> bool:
    return len(a) == len(b) and all(
        x == y or (isinstance(x, float) and isinstance(y, float) and math.isnan(x) and math.isnan(y))
        for x, y in zip(a, b, strict=True)
    )


# -- files -------------------------------------------------------------------------------------


def _open_backup(path: Path) -> duckdb.DuckDBPyConnection:
    try:
        con = duckdb.connect(str(path), read_only=True)
    except duckdb.Error as exc:
        raise BackupRefused(f"{path} is not a DuckDB backup: {exc}") from None
    if not _has_table(con, "schema_migrations"):
        con.close()
        raise BackupRefused(f"{path} is a DuckDB file without tsdb-service history")
    return con


def _has_table(con: duckdb.DuckDBPyConnection, name: str) -> bool:
    rows = con.execute(
        "SELECT count(*) FROM duckdb_tables() WHERE database_name = current_database() AND table_name = ?", [name]
    ).fetchall()
    return bool(rows[0][0])


def _refuse_existing(path: Path, what: str) -> None:
    if path.exists():
        raise BackupRefused(f"{what} {path} exists: it is never overwritten; name a new one, or move it away first")


def _install(partial: Path, target: Path, report: BackupReport) -> None:
    """Rename the checked copy into place, durably; never over a file. A
    copy that did not check out is not kept (the caller removes it)."""
    if not report.verified:
        raise BackupNotVerified(
            "the copy read back differs from its source, so it was not kept: " + " / ".join(report.lines())
        )
    appeared = BackupRefused(f"{target} appeared while the copy was made: it is kept, the copy is not")
    try:
        os.link(partial, target)  # fails if the target appeared meanwhile
        partial.unlink()
    except FileExistsError:
        raise appeared from None
    except OSError:  # a file system without hard links
        if target.exists():
            raise appeared from None
        os.rename(partial, target)
    fsync_path(target.parent)


def _remove(path: Path) -> None:
    for leftover in (path, Path(str(path) + ".wal")):
        with contextlib.suppress(FileNotFoundError):
            leftover.unlink()
