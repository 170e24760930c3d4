"""Storage backends behind one seam (see ``base``)."""

from __future__ import annotations

from ..config import Settings
from .base import Store


def open_store(settings: Settings, *, background: bool = False) -> Store:
    """Open the backend named by ``settings.db``; migrations run on open.

    ``background`` (the server): also start the retention worker when a
    policy is set (``storage.retention``). Offline commands (copy, compact)
    never delete by retention behind the operator's back."""
    from .retention import attach_retention

    store = _open_backend(settings)
    try:
        attach_retention(store, settings, start=background)
    except BaseException:
        store.close()
        raise
    return store


def _open_backend(settings: Settings) -> Store:
    if settings.backend == "postgresql":
        from .postgres_store import PostgresStore

        return PostgresStore(settings.db, writer_threads=settings.writer_threads or 3)
    from .duckdb_store import DuckDBStore

    return DuckDBStore(
        settings.db,
        compact_rows=settings.compact_rows,
        major_compact_runs=settings.major_compact_runs,
        writer_threads=settings.writer_threads or 1,
        tail_series=settings.tail_cache_series,
        tail_rows=settings.tail_cache_rows,
        tail_samples=settings.tail_cache_samples,
    )
