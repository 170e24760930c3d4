"""Whole-store and bulk reads: exports, copies, counts.

``SampleBatches`` is what crosses the seam for an export: the columns of
``EXPORT_COLUMNS``, a batch at a time, oldest sample first.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import ExitStack
from datetime import datetime
from typing import Protocol

import pyarrow as pa

from tsdb_service.core.errors import Unavailable
from tsdb_service.core.query import StoredSample
from tsdb_service.read.requests import ExportRead

# The columns of every batch, in this order. ``time`` is a naive UTC
# timestamp (DuckDB) or epoch microseconds (PostgreSQL); the rest as named.
# Exactly one value column is set per sample, chosen by how it is stored.
EXPORT_COLUMNS = (
    "time",
    "entity_id",
    "entity_type",
    "service_path",
    "attribute",
    "ngsi_type",
    "value_number",  # Number, Integer
    "value_text",  # Text, DateTime (ISO), Relationship (target id)
    "value_bool",  # Boolean
    "value_json",  # StructuredValue, arrays, geometry: JSON as received
)
Columns = list[pa.Array]


class BulkReader(Protocol):
    def export_batches(self, ask: ExportRead) -> SampleBatches:
        """The samples of ``ask.sids`` in ``ask.time`` (inclusive) joined with
        their series' names, oldest first (time, then row, then series), as
        ``SampleBatches`` of at most ``ask.batch_rows`` samples in the columns
        ``EXPORT_COLUMNS``: what an export writes.

        Memory stays bounded: DuckDB sorts consecutive time windows of about
        ``ask.sort_rows`` samples (memory follows the window), PostgreSQL
        streams a server-side cursor. The query starts here (a failure to
        start is raised here, before any batch); the stream holds a cursor
        of its own (PostgreSQL: a pooled connection and one transaction, one
        snapshot) until ``close()``, which the caller must call (a context
        manager). Use it from one thread at a time, never on the event loop."""
        ...

    def sample_counts(self) -> dict[str, int]:
        """Stored samples per tenant (a full scan: for commands, not routes)."""
        ...

    def type_counts(self, before: datetime | None = None) -> dict[tuple[str, str], tuple[int, int]]:
        """(entity notifications, samples) stored per (tenant, entity type),
        only those timed before ``before`` when given: a full scan, for an
        import's check (``tsdb-service import quantumleap``)."""
        ...

    def stored_samples(self, batch_rows: int) -> Iterator[list[StoredSample]]:
        """Every stored sample in (row, instance) order, in lists of at most
        ``batch_rows``: what a copy reads. The iterator holds a cursor of its
        own (PostgreSQL: a pooled connection and one transaction, so the
        whole stream is one snapshot) until it is exhausted or closed; use
        it from one thread."""
        ...


class SampleBatches:
    """Batches of export columns (``EXPORT_COLUMNS``); ``next()`` is None at the end.

    Holds a database cursor (PostgreSQL: a pooled connection in one
    transaction, so the stream is one snapshot) from ``BulkReader.export_batches``
    until ``close()``; use it as a context manager. Not thread-safe: one
    thread at a time (successive calls may come from different threadpool
    threads, never at once), never on the event loop. A database failure
    while reading is ``errors.Unavailable``."""

    def __init__(self) -> None:
        self.resources = ExitStack()
        self.read: Callable[[], Columns | None] = _nothing

    def next(self) -> Columns | None:
        try:
            return self.read()
        except Exception as exc:
            if isinstance(exc, Unavailable) or not _is_database_error(exc):
                raise
            raise Unavailable(f"the database is not available: {exc}") from None

    def close(self) -> None:
        self.read = _nothing
        self.resources.close()

    def __enter__(self) -> SampleBatches:
        return self

    def __exit__(self, *exc_info) -> None:
        self.close()


def _nothing() -> None:
    return None


def _is_database_error(exc: Exception) -> bool:
    module = type(exc).__module__ or ""
    return module.startswith(("duckdb", "psycopg"))
