"""Whether a command is about to create a new, empty DuckDB database.

``serve``, ``migrate`` and the imports say so in one line: a mistyped
``--db`` path otherwise starts an empty store silently. Asked before the
store opens (opening creates the file).
"""

from __future__ import annotations

from pathlib import Path

from tsdb_service.core.config import Settings


def new_duckdb_file(settings: Settings) -> Path | None:
    """The DuckDB file ``settings.db`` names when it does not exist yet (the
    store will create it), as an absolute path; None otherwise. Asked before
    the store opens, so a mistyped path is said once: a new, empty database."""
    if settings.backend != "duckdb" or settings.db == ":memory:":
        return None
    path = Path(settings.db).resolve()
    return None if path.exists() else path
