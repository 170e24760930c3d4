"""Settings from flags and ``TSDB_*`` environment variables.

``get_settings()`` is the one place the app reads configuration; tests and
the CLI override it by passing a ``Settings`` to ``create_app``.
"""

from __future__ import annotations

import re
from functools import lru_cache

from pydantic import Field, ValidationError, field_validator
from pydantic_settings import BaseSettings, SettingsConfigDict

MIB = 1024 * 1024
LOG_LEVELS = ("critical", "error", "warning", "info", "debug", "trace")
POSTGRES_PREFIXES = ("postgresql://", "postgres://")
# "scheme:" at the start of --db; one letter is a Windows drive ("C:\\data"), not a scheme.
_SCHEME = re.compile(r"^([A-Za-z][A-Za-z0-9+.-]+):")


class Settings(BaseSettings):
    model_config = SettingsConfigDict(env_prefix="TSDB_", extra="ignore")

    db: str = Field(
        "./data/tsdb.duckdb",
        description="A DuckDB file path (embedded default) or a postgresql:// URL.",
    )
    host: str = Field("0.0.0.0", description="Address to bind, as QuantumLeap does.")
    port: int = Field(8668, ge=1, le=65535, description="QuantumLeap's port.")
    workers: int = Field(1, ge=1, description="uvicorn workers; PostgreSQL only.")
    max_body_bytes: int = Field(1 * MIB, ge=1024, description="Larger notifications get 413.")
    default_limit: int = Field(10_000, ge=1, description="Rows returned when no limit is given.")
    compact_rows: int = Field(
        500_000, ge=1000, description="Move the hot table into the sorted one at this many rows."
    )
    major_compact_runs: int = Field(
        8, ge=1, description="Rewrite the sorted table after this many compactions into it."
    )
    writer_threads: int | None = Field(
        None, ge=1, le=16,
        description="Group-commit writer threads; default 1 on DuckDB (more only contend for the GIL), "
        "3 on PostgreSQL (commits wait on the network, so they overlap).",
    )
    tail_cache_series: int = Field(
        8192, ge=0, description="DuckDB: sizes the in-memory tails (0: off); see tail_cache_samples."
    )
    tail_cache_rows: int = Field(128, ge=0, description="DuckDB: newest samples kept per cached series.")
    tail_cache_samples: int = Field(
        1_000_000, ge=0, description="DuckDB: samples kept in all tails (~200 bytes each), oldest-read out first."
    )
    log_level: str = Field("info", description=f"One of {', '.join(LOG_LEVELS)}.")
    access_log: bool = Field(False, description="Log every request (uvicorn's access log).")

    @field_validator("db")
    @classmethod
    def _db_is_a_file_or_a_postgres_url(cls, value: str) -> str:
        """Only two kinds of --db exist. Anything else (``postgress://``,
        ``mysql://``, ``postgresql:/x``) would otherwise become a DuckDB file
        of that name, silently taking data meant for another database."""
        return check_db(value)

    @field_validator("host")
    @classmethod
    def _host_not_empty(cls, value: str) -> str:
        if not value.strip():
            raise ValueError("is empty: give an address to bind, e.g. 0.0.0.0 or 127.0.0.1")
        return value.strip()

    @field_validator("log_level")
    @classmethod
    def _known_log_level(cls, value: str) -> str:
        level = value.strip().lower()
        if level not in LOG_LEVELS:
            raise ValueError(f"unknown log level {value!r}: choose from {', '.join(LOG_LEVELS)}")
        return level

    @property
    def backend(self) -> str:
        return "postgresql" if self.db.startswith(("postgresql://", "postgres://")) else "duckdb"


def check_db(value: str) -> str:
    """A DuckDB file path or a ``postgresql://`` / ``postgres://`` URL; else ValueError."""
    db = value.strip()
    if not db:
        raise ValueError("is empty: give a DuckDB file path or a postgresql:// URL")
    if db.startswith(POSTGRES_PREFIXES):
        return db
    match = _SCHEME.match(db)
    if match is None:
        return db
    scheme = match[1]
    if scheme.lower() in ("postgresql", "postgres"):
        raise ValueError(f"{db!r} is not a PostgreSQL URL: write postgresql://user@host:port/database")
    if db[match.end():].startswith("//"):
        raise ValueError(f"{db!r}: unsupported scheme {scheme}:// (only postgresql:// or postgres:// URLs "
                         "and DuckDB file paths)")  # fmt: skip
    raise ValueError(f"{db!r} starts like a URL ({scheme}:): give a postgresql:// URL or a DuckDB file path "
                     f"(./{db} for a file name with a colon)")  # fmt: skip


class SettingsError(ValueError):
    """A setting is invalid; the message is one line naming the flag and its variable."""


def load_settings(**overrides) -> Settings:
    """``Settings`` from ``overrides`` and ``TSDB_*`` variables, or one ``SettingsError``
    line per problem joined with "; " (pydantic's report spans many lines)."""
    try:
        return Settings(**overrides)
    except ValidationError as exc:
        raise SettingsError(describe(exc)) from None


def describe(exc: ValidationError) -> str:
    """pydantic's errors as ``--port (TSDB_PORT): must be at most 65535, got 99999``."""
    problems = []
    for error in exc.errors():
        name = str(error["loc"][0]) if error["loc"] else "settings"
        message = error["msg"]
        for prefix in ("Value error, ", "Input should be "):
            if message.startswith(prefix):
                message = ("must be " if prefix == "Input should be " else "") + message[len(prefix):]
        flag = f"--{name.replace('_', '-')} (TSDB_{name.upper()})"
        problems.append(f"{flag}: {message}, got {error['input']!r}" if error["type"] != "value_error"
                        else f"{flag}: {message}")  # fmt: skip
    return "; ".join(problems)


@lru_cache(maxsize=1)
def get_settings() -> Settings:
    return Settings()
