"""Versioned schema migrations from ``migrations/*.sql``.

File names are ``NNNN_name.sql`` (every backend) or ``NNNN_name.<backend>.sql``
(one backend, where the dialects differ). Each version is applied once, in
order, inside a transaction that also records it in ``schema_migrations``,
so running ``migrate`` twice is harmless.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any, Protocol

_NAME = re.compile(r"^(\d{4})_([A-Za-z0-9_]+)(?:\.(duckdb|postgresql))?\.sql$")


@dataclass(frozen=True)
class Migration:
    version: int
    name: str
    sql: str


class SqlConnection(Protocol):
    def execute(self, sql: str, params: Any = ..., /) -> Any: ...


def migrations_dir() -> Path:
    """The SQL files: packaged in a wheel, or the repository's ``migrations/``
    in an editable install."""
    packaged = resources.files("tsdb_service") / "_migrations"
    if packaged.is_dir():
        return Path(str(packaged))
    return Path(__file__).resolve().parents[2] / "migrations"


def load_migrations(backend: str, directory: Path | None = None) -> list[Migration]:
    found: dict[int, Migration] = {}
    for path in sorted((directory or migrations_dir()).glob("*.sql")):
        match = _NAME.match(path.name)
        if not match:
            continue
        version, name, only_for = int(match[1]), match[2], match[3]
        if only_for not in (None, backend):
            continue
        if version in found:
            raise RuntimeError(f"two migrations with version {version} for {backend}")
        found[version] = Migration(version, name, path.read_text(encoding="utf-8"))
    return [found[v] for v in sorted(found)]


SCHEMA_TABLE = """
CREATE TABLE IF NOT EXISTS schema_migrations (
    version    INTEGER PRIMARY KEY,
    name       VARCHAR NOT NULL,
    applied_at TIMESTAMP NOT NULL DEFAULT CURRENT_TIMESTAMP
)
"""


def applied_versions(conn: SqlConnection) -> set[int]:
    conn.execute(SCHEMA_TABLE)
    rows = conn.execute("SELECT version FROM schema_migrations").fetchall()
    return {int(r[0]) for r in rows}


def split_statements(sql: str) -> list[str]:
    """Split on semicolons at line ends; our migration files keep one
    statement per ``;``-terminated block and no semicolons in strings."""
    parts, current = [], []
    for line in sql.splitlines():
        current.append(line)
        if line.rstrip().endswith(";"):
            parts.append("\n".join(current))
            current = []
    tail = "\n".join(current).strip()
    if tail and not all(line.strip().startswith("--") or not line.strip() for line in current):
        parts.append(tail)
    return [p for p in parts if p.strip()]
