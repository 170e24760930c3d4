"""Storage backends behind the two seams (``read``, ``write``): DuckDB
(``duckdb``) and PostgreSQL (``postgres``) on the SQL they share (``sql``),
each a ``store.Store``.

Opening a store is where an operator's mistakes show up: a DuckDB file held
by another process, a directory we cannot write, a PostgreSQL server that is
down, a database or role that does not exist. ``open_store`` turns each into
a ``StoreUnavailable`` whose message is one line saying what is wrong and
what to do, so every command (and the service's start-up) can print it
instead of a driver's traceback.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from tsdb_service.core.backup import BackupRefused, BackupReport
from tsdb_service.core.config import Settings
from tsdb_service.storage.rejected import RejectedLimits
from tsdb_service.storage.store import Store
from tsdb_service.write.log import LogRefused

PG_CONNECT_TIMEOUT_S = 10


class StoreUnavailable(RuntimeError):
    """The store cannot be opened; the message is one line for an operator."""


def migrate(settings: Settings) -> list[int]:
    """Apply pending schema migrations to ``settings.db`` without opening a
    store (``tsdb-service migrate``); the versions applied. An operator's
    mistake is a one-line ``StoreUnavailable``, as for ``open_store``."""
    with explained(settings.db):
        if settings.backend == "postgresql":
            from tsdb_service.storage.postgres.store import migrate_url

            return migrate_url(settings.db)
        from tsdb_service.storage.duckdb.connection import connect, migrate_duckdb

        con = connect(settings.db)
        try:
            return migrate_duckdb(con)
        finally:
            con.close()


def open_store(settings: Settings, *, background: bool = False) -> Store:
    """Open the backend named by ``settings.db``; migrations run on open.

    ``background`` (the server): also start the retention worker when a
    policy is set (``storage.retention``). Offline commands (copy, compact)
    never delete by retention behind the operator's back."""
    from tsdb_service.storage.retention import attach_retention

    store = _open_explained(settings)
    try:
        attach_retention(store, settings, start=background)
    except BaseException:
        store.close()
        raise
    return store


@contextmanager
def explained(db: str) -> Iterator[None]:
    """Let an operator's mistakes with ``db`` (see ``explain``) out as
    one-line ``StoreUnavailable``s; anything else as it is."""
    try:
        yield
    except StoreUnavailable:
        raise
    except Exception as exc:
        message = explain(exc, db)
        if message is None:
            raise
        raise StoreUnavailable(message) from exc


def _open_explained(settings: Settings) -> Store:
    """``_open``, with an operator's mistakes as one-line ``StoreUnavailable``s."""
    with explained(settings.db):
        return _open(settings)


def _open(settings: Settings) -> Store:
    if settings.backend == "postgresql":
        from tsdb_service.storage.postgres.store import PostgresStore

        return PostgresStore(
            settings.db,
            writer_threads=settings.writer_threads or 3,
            agg_partials_hours=settings.agg_partials_hours,
            rejected_limits=RejectedLimits.from_settings(settings),
        )
    from tsdb_service.storage.duckdb.store import DuckDBStore

    return DuckDBStore(
        settings.db,
        compact_rows=settings.compact_rows,
        major_compact_runs=settings.major_compact_runs,
        writer_threads=settings.writer_threads or 1,
        tail_series=settings.tail_cache_series,
        tail_rows=settings.tail_cache_rows,
        tail_samples=settings.tail_cache_samples,
        agg_partials_hours=settings.agg_partials_hours,
        checkpoint_bytes=settings.wal_checkpoint_bytes,
        rejected_limits=RejectedLimits.from_settings(settings),
        ingest_log=settings.ingest_log,
        ingest_log_lag_bytes=settings.ingest_log_lag_bytes,
    )


def restore_backup(backup: str, db: str) -> BackupReport:
    """Make the new store ``db`` from the backup file ``backup`` (DuckDB;
    ``storage.duckdb.backup``), checked against it."""
    if Settings(db=db).backend != "duckdb":
        raise BackupRefused("restore makes a DuckDB file; PostgreSQL restores with pg_restore (docs/operations.md)")
    from tsdb_service.storage.duckdb.backup import restore_backup as restore_duckdb

    return restore_duckdb(Path(backup), Path(db))


def check_store(settings: Settings) -> None:
    """Connect once and disconnect, raising ``StoreUnavailable`` on failure.

    Cheap (no migrations, no caches): ``serve`` calls it before starting the
    web server, so a wrong ``--db`` is one line and exit status 2 rather than
    a failed application start-up inside uvicorn.
    """
    with explained(settings.db):
        if settings.backend == "postgresql":
            import psycopg

            psycopg.connect(settings.db, connect_timeout=PG_CONNECT_TIMEOUT_S).close()
            return
        import duckdb

        if settings.db != ":memory:":
            Path(settings.db).parent.mkdir(parents=True, exist_ok=True)
        duckdb.connect(settings.db).close()


def require_history(db: str) -> None:
    """``db`` must already hold tsdb-service history: a source to copy from or
    a file to compact is never created by accident (a typo would otherwise
    make an empty database and report success)."""
    if Settings(db=db).backend == "postgresql":
        _require_pg_schema(db)
        return
    path = Path(db)
    if not path.exists():
        raise StoreUnavailable(f"{db} does not exist")
    if not path.is_file():
        raise StoreUnavailable(f"{db} is not a file")
    import duckdb

    try:
        con = duckdb.connect(db, read_only=True)
    except Exception as exc:
        raise StoreUnavailable(explain(exc, db) or str(exc)) from exc
    try:
        row = con.execute(
            "SELECT count(*) FROM information_schema.tables WHERE table_name = 'schema_migrations'"
        ).fetchone()
        found = row is not None and row[0]
    finally:
        con.close()
    if not found:
        raise StoreUnavailable(f"{db} is a DuckDB file without tsdb-service history")


def _require_pg_schema(url: str) -> None:
    import psycopg

    try:
        with psycopg.connect(url, connect_timeout=PG_CONNECT_TIMEOUT_S) as conn:
            row = conn.execute("SELECT to_regclass('schema_migrations') IS NOT NULL").fetchone()
            found = row is not None and row[0]
    except Exception as exc:
        raise StoreUnavailable(explain(exc, url) or str(exc)) from exc
    if not found:
        raise StoreUnavailable(f"{redact(url)} holds no tsdb-service history")


def explain(exc: BaseException, db: str) -> str | None:
    """One line for a failure to open ``db``, or None when it is not an
    operator's problem (then the traceback is wanted: it is a bug)."""
    if isinstance(exc, LogRefused):  # another database's log, or one without identity: it says what to do
        return str(exc)
    if isinstance(exc, OSError):
        return _explain_os(exc, db)
    module = type(exc).__module__
    if module.startswith(("duckdb", "_duckdb")):
        return _explain_duckdb(exc, db)
    if module.startswith("psycopg"):
        return _explain_pg(exc, db)
    if isinstance(exc, RuntimeError) and exc.__cause__ is not None:  # e.g. the lock message of connect()
        return explain(exc.__cause__, db) or str(exc)
    return None


def _explain_os(exc: OSError, db: str) -> str:
    reason = (exc.strerror or str(exc)).lower()
    if exc.filename and str(Path(db).parent).startswith(str(exc.filename)):
        return f"cannot create the directory of {db}: {reason} ({exc.filename})"
    return f"cannot use {db}: {reason}" + (f" ({exc.filename})" if exc.filename else "")


def _explain_duckdb(exc: BaseException, db: str) -> str | None:
    text = str(exc)
    if "lock" in text.lower():
        pid = re.search(r"\(PID (\d+)\)", text)
        holder = f" (PID {pid[1]})" if pid else ""
        return (
            f"{db} is open in another process{holder}: DuckDB allows one process per file; stop it, "
            "or use PostgreSQL (--db postgresql://...) to run several"
        )
    if "Permission denied" in text:
        return f"cannot write {db}: permission denied (is {Path(db).parent or '.'} writable by this user?)"
    if "not a valid DuckDB database file" in text:
        return f"{db} is not a DuckDB database file"
    if "Is a directory" in text:
        return f"{db} is a directory: give a file path, e.g. {Path(db) / 'tsdb.duckdb'}"
    if "Cannot open file" in text or "No such file" in text:
        return f"cannot open {db}: {text.rsplit(':', 1)[-1].strip()}"
    if "IO Error" in text:
        return f"cannot use {db}: {_one_line(text)}"
    return None


def _explain_pg(exc: BaseException, db: str) -> str | None:
    text = _one_line(str(exc)).removeprefix("connection failed: ")
    where = redact(db)
    database = re.search(r'database "([^"]+)" does not exist', text)
    if database:
        return f"PostgreSQL database {database[1]!r} does not exist ({where}): create it (createdb {database[1]})"
    role = re.search(r'role "([^"]+)" does not exist', text)
    if role:
        return f"PostgreSQL role {role[1]!r} does not exist ({where}): create it (CREATE ROLE ... LOGIN)"
    import psycopg

    if isinstance(exc, psycopg.errors.InsufficientPrivilege):
        return f"PostgreSQL refused {where}: {text}"
    if isinstance(exc, psycopg.OperationalError):
        return f"cannot connect to PostgreSQL at {where}: {text}"
    return None


def _one_line(text: str) -> str:
    return " ".join(text.split())


def redact(url: str) -> str:
    """A URL fit for messages and logs: the password replaced by ``***``."""
    return re.sub(r"^(postgres(?:ql)?://[^:/@]*):[^@/]*@", r"\1:***@", url)
