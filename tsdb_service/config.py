"""Settings from flags and ``TSDB_*`` environment variables.

``get_settings()`` is the one place the app reads configuration; tests and
the CLI override it by passing a ``Settings`` to ``create_app``.
"""

from __future__ import annotations

from functools import lru_cache

from pydantic import Field
from pydantic_settings import BaseSettings, SettingsConfigDict

MIB = 1024 * 1024


class Settings(BaseSettings):
    model_config = SettingsConfigDict(env_prefix="TSDB_", extra="ignore")

    db: str = Field(
        "./data/tsdb.duckdb",
        description="A DuckDB file path (embedded default) or a postgresql:// URL.",
    )
    host: str = Field("0.0.0.0", description="Address to bind, as QuantumLeap does.")
    port: int = Field(8668, description="QuantumLeap's port.")
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
    wal_checkpoint_bytes: int = Field(
        16 * MIB, ge=64 * 1024,
        description="DuckDB: fold the write-ahead log into the database file once it is this big.",
    )
    log_level: str = "info"
    access_log: bool = False

    @property
    def backend(self) -> str:
        return "postgresql" if self.db.startswith(("postgresql://", "postgres://")) else "duckdb"


@lru_cache(maxsize=1)
def get_settings() -> Settings:
    return Settings()
