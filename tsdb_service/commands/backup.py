"""``tsdb-service backup`` and ``restore``: consistent copies of a DuckDB store.

Three ways, one copy (``storage.duckdb.backup``):

* **beside a stopped store** (``backup_stopped``): the store is opened as
  the service opens it (its ingest log replayed), copied, and closed;
* **through the running service** (``backup_through``): a DuckDB file
  belongs to one process, so the service itself takes the copy when asked
  (``POST /admin/backup``), into the directory its operator configured
  (``TSDB_BACKUP_DIR``), and answers with the report;
* **restore** (``restore``): a backup becomes a new store file, never over
  an existing one.

Each reads its copy back (row counts, sampled rows) and says so in its
report; a copy that does not check out is not kept. PostgreSQL is backed up
with its own tools (docs/operations.md, "Backups").
"""

from __future__ import annotations

from pathlib import Path

import httpx

from tsdb_service.core.backup import BackupNotVerified, BackupRefused, BackupReport
from tsdb_service.core.config import Settings

BACKUP_PATH = "/admin/backup"
TIMEOUT_S = 3600.0  # a big store takes a while to copy; the service answers when it is done


def backup_stopped(db: str, target: str) -> BackupReport:
    """Back up the DuckDB store ``db`` (not in use by a service) into the new file ``target``."""
    from tsdb_service.storage import StoreUnavailable, open_store, require_history

    if Settings(db=db).backend != "duckdb":
        raise BackupRefused("PostgreSQL is backed up with pg_dump or pg_basebackup: see docs/operations.md, 'Backups'")
    if Path(target).exists():
        raise BackupRefused(f"{target} exists: a backup never overwrites a file; name a new one")
    try:
        require_history(db)
        store = open_store(Settings(db=db))
    except StoreUnavailable as exc:
        if "another process" in str(exc):
            raise BackupRefused(
                f"{db} is in use by a running tsdb-service: take the backup through it, "
                "tsdb-service backup --url http://HOST:PORT [NAME] (written in its TSDB_BACKUP_DIR)"
            ) from None
        raise
    try:
        return store.backup(target)
    finally:
        store.close()


def backup_through(url: str, name: str | None, api_key: str | None) -> BackupReport:
    """Ask the service at ``url`` for a backup named ``name`` (in its
    backup directory; None: a name with the time in it)."""
    headers = {"Authorization": f"Bearer {api_key}"} if api_key else {}
    body = {"name": name} if name else {}
    try:
        answer = httpx.post(url.rstrip("/") + BACKUP_PATH, json=body, headers=headers, timeout=TIMEOUT_S)
    except httpx.HTTPError as exc:
        raise BackupRefused(f"cannot reach {url}: {exc}") from None
    try:
        doc = answer.json()
    except ValueError:
        doc = {}
    if answer.status_code != 201:
        reason = doc.get("description") if isinstance(doc, dict) else None
        failure = BackupNotVerified if answer.status_code == 500 else BackupRefused
        raise failure(f"{url} answered {answer.status_code}: {reason or answer.text[:300]}")
    return BackupReport.from_json(doc)


def restore(backup: str, db: str) -> BackupReport:
    """Make the new DuckDB store file ``db`` from the backup file ``backup``."""
    from tsdb_service.storage import restore_backup

    return restore_backup(backup, db)
