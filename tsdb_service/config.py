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
    # --- limits (issue 12): read budgets, rejected-store bounds, slow clients ---
    read_max_series: int = Field(
        50_000, ge=1, description="Series one request may select (per resolution step); more: 422 QueryTooLarge.",
    )
    read_max_rows: int = Field(
        500_000, ge=1, description="Samples and aggregate rows one request may read in all; more: 422 QueryTooLarge.",
    )
    read_max_response_bytes: int = Field(
        64 * MIB, ge=1024, description="Largest answer a read may render; larger: 422 QueryTooLarge.",
    )
    read_max_seconds: float = Field(
        20.0, gt=0, description="Wall time of one read, checked between its steps; past it: 422 QueryTooLarge.",
    )
    rejected_max_per_tenant: int = Field(
        1000, ge=1, description="Rejected notifications kept per tenant; the oldest are dropped first.",
    )
    rejected_max_bytes_per_tenant: int = Field(
        64 * MIB, ge=1024, description="Bytes of rejected bodies and headers kept per tenant; oldest dropped first "
        "(a tenant's newest rejection is always kept).",
    )
    rejected_max_age_days: float = Field(
        30.0, gt=0, description="Rejected notifications older than this are dropped (when the next is recorded).",
    )
    rejected_page_max_bytes: int = Field(
        8 * MIB, ge=1024, description="A rejected listing stops before this many bytes (at least one row) and "
        "points to the next page.",
    )
    header_timeout_s: float = Field(
        10.0, gt=0, description="Close a connection whose request headers are not complete this long after it "
        "opened (or after the request's first byte).",
    )
    body_timeout_s: float = Field(
        60.0, gt=0, description="Cut off a request whose body is not complete this long after its headers.",
    )
    max_connections: int = Field(
        4096, ge=1, description="Open connections per process; past it a new connection gets 503 and is closed.",
    )
    keep_alive_s: int = Field(5, ge=1, description="Close a kept-alive connection idle this long between requests.")
    # --- end of limits ---
    log_level: str = "info"
    access_log: bool = False

    @property
    def backend(self) -> str:
        return "postgresql" if self.db.startswith(("postgresql://", "postgres://")) else "duckdb"


@lru_cache(maxsize=1)
def get_settings() -> Settings:
    return Settings()
