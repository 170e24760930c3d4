"""Settings from flags and ``TSDB_*`` environment variables.

``get_settings()`` is the one place the app reads configuration; tests and
the CLI override it by passing a ``Settings`` to ``create_app``.
"""

from __future__ import annotations

from functools import lru_cache

from pydantic import Field, field_validator
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
    max_body_bytes: int = Field(
        9 * MIB, ge=1024,
        description="Larger notifications get 413 (and are kept in the rejected store). Orion sends "
        "notifications of up to 8 MB by default (its -outReqMsgMaxSize): the default leaves headroom above it.",
    )
    rejected_body_max_bytes: int = Field(
        16 * MIB, ge=0,
        description="The rejected store keeps a rejected notification's body up to this many bytes "
        "(its full size is recorded, and that it was truncated).",
    )
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
    log_level: str = "info"
    access_log: bool = False

    # --- Retention and rollups (storage/retention.py, storage/rollups.py; README "Retention and rollups") ---
    retention: str = Field(
        "", description="How long raw samples are kept, per tenant and entity type: "
        "'*=365d,acme=30d,acme/Robot=7d' (or the same as a JSON object); empty: forever.",
    )
    rollups: bool = Field(
        False, description="Fold the samples retention deletes into hourly count/sum/min/max per series, "
        "which aggregation queries (aggrPeriod hour or longer, or none) keep answering from.",
    )
    rollup_retention: str = Field(
        "", description="How long hourly rollups are kept, same syntax as retention; empty: forever.",
    )
    retention_interval: float = Field(300.0, gt=0, description="Seconds between retention passes.")
    retention_batch_rows: int = Field(
        50_000, ge=1, description="Rows deleted per batch and table, each batch its own short transaction.",
    )
    retention_pause: float = Field(0.05, ge=0, description="Seconds to pause between retention batches.")

    @field_validator("retention", "rollup_retention")
    @classmethod
    def _retention_spec(cls, value: str, info) -> str:
        from .storage.retention import RetentionPolicy

        RetentionPolicy.parse(value, setting="TSDB_" + info.field_name.upper())  # raises ValueError
        return value
    # --- end of retention and rollups ---

    @property
    def backend(self) -> str:
        return "postgresql" if self.db.startswith(("postgresql://", "postgres://")) else "duckdb"


@lru_cache(maxsize=1)
def get_settings() -> Settings:
    return Settings()
