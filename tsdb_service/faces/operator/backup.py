"""``POST /admin/backup``: a consistent, checked copy of the running store.

A DuckDB file belongs to one process, so the service takes the copy itself
(``tsdb-service backup --url`` asks it). Off unless the operator names a
directory (``TSDB_BACKUP_DIR``); a request names only a file in it (a
plain name: no directory, no path), never an existing one. Admin scope
(``security.principals``), and a credential restricted to no tenant: a
backup holds every tenant. The copy holds everything acknowledged before
the request (the store applies its ingest log first); the answer is the
report of what was copied and checked.
"""

from __future__ import annotations

import re
from datetime import UTC, datetime
from functools import partial
from pathlib import Path

import orjson
from fastapi import APIRouter, Request

from tsdb_service.core.backup import BackupRefused
from tsdb_service.core.errors import BadRequest
from tsdb_service.faces.operator import openapi as ops_oa
from tsdb_service.http.responses import JSON
from tsdb_service.http.store import store_of
from tsdb_service.http.tenancy import require_every_tenant

router = APIRouter(tags=["meta"])
# A file name: no separator, no leading dot, nothing a shell or a path would read twice.
_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,127}")


@router.post("/admin/backup", status_code=201, summary="Back up the store (DuckDB)", **ops_oa.BACKUP)
async def backup(request: Request) -> JSON:
    """Copy the whole store, with everything acknowledged before this
    request, into a new file of the configured backup directory, read the
    copy back and answer with what was checked."""
    require_every_tenant(request, "a backup")
    folder = request.app.state.settings.backup_dir
    if not folder:
        raise BackupRefused(
            "backups through the service are off: set TSDB_BACKUP_DIR to the directory to write them in"
        )
    target = Path(folder) / _name(await request.body())
    store = store_of(request)
    report = await store.read(partial(store.backup, str(target)), memory_first=False)
    return JSON(report.as_json(), status_code=201)


def _name(body: bytes) -> str:
    """The file name the body asks for (``{"name": "..."}``), or one with
    the time in it."""
    doc = {}
    if body.strip():
        try:
            doc = orjson.loads(body)
        except orjson.JSONDecodeError:
            raise BadRequest('the body must be a JSON object, e.g. {"name": "nightly.duckdb"}') from None
        if not isinstance(doc, dict) or set(doc) - {"name"}:
            raise BadRequest('the body may hold only {"name": FILE NAME}')
    name = doc["name"] if "name" in doc else f"tsdb-{datetime.now(UTC).strftime('%Y%m%dT%H%M%SZ')}.duckdb"
    if not isinstance(name, str) or not _NAME.fullmatch(name):
        raise BadRequest(
            "name: a file name of up to 128 letters, digits, '.', '_' or '-', not starting with '.' "
            "(the backup directory is the operator's setting)"
        )
    return name
