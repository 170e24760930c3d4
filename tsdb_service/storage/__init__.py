"""Storage backends behind one seam (see ``base``)."""

from __future__ import annotations

from ..config import Settings
from .base import Store
from .rejected import RejectedLimits


def open_store(settings: Settings) -> Store:
    """Open the backend named by ``settings.db``; migrations run on open."""
    if settings.backend == "postgresql":
        from .postgres_store import PostgresStore

        return PostgresStore(settings.db, writer_threads=settings.writer_threads or 3,
                             rejected_limits=RejectedLimits.from_settings(settings))
    from .duckdb_store import DuckDBStore

    return DuckDBStore(
        settings.db,
        compact_rows=settings.compact_rows,
        major_compact_runs=settings.major_compact_runs,
        writer_threads=settings.writer_threads or 1,
        tail_series=settings.tail_cache_series,
        tail_rows=settings.tail_cache_rows,
        tail_samples=settings.tail_cache_samples,
        checkpoint_bytes=settings.wal_checkpoint_bytes,
        rejected_limits=RejectedLimits.from_settings(settings),
    )
