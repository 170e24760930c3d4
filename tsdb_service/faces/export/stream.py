"""The selected samples as a stream of Arrow record batches, on both backends.

Series are resolved on the querier's catalog, exactly as history queries
resolve them; the samples are then read through the read seam
(``Querier.export_batches``, rendered in ``storage.sql.bulk``: by series id,
bound values only, joined with ``series`` for the names). Rows come oldest
first (time, then the notification, then the series), ``BATCH_ROWS`` at a
time, so memory stays bounded whatever the export's size: DuckDB sorts one
time window of about ``WINDOW_ROWS`` samples at a time (it sorts in
memory), PostgreSQL streams a server-side cursor. Here the columns become
record batches in ``SCHEMA``.

Every call here blocks: callers run it in a thread, never on the event loop.
"""

from __future__ import annotations

from collections.abc import Callable
from contextlib import ExitStack
from functools import partial

import pyarrow as pa

from tsdb_service.faces.export.query import ExportQuery
from tsdb_service.read import Reader
from tsdb_service.read.bulk import EXPORT_COLUMNS, SampleBatches
from tsdb_service.read.requests import ExportRead, SeriesSelect

BATCH_ROWS = 131_072
WINDOW_ROWS = 1_000_000  # DuckDB: samples sorted at once (``Querier.export_batches``)
UTC_MICROS = pa.timestamp("us", tz="UTC")

# The export layout (docs/operations.md, "Export"). Exactly one value column is set per
# sample, chosen by how the sample is stored; all four are null for null.
SCHEMA = pa.schema(
    [
        pa.field("time", UTC_MICROS, nullable=False),
        pa.field("entity_id", pa.string(), nullable=False),
        pa.field("entity_type", pa.string(), nullable=False),
        pa.field("service_path", pa.string(), nullable=False),
        pa.field("attribute", pa.string(), nullable=False),
        pa.field("ngsi_type", pa.string()),
        pa.field("value_number", pa.float64()),  # Number, Integer
        pa.field("value_text", pa.string()),  # Text, DateTime (ISO), Relationship (target id)
        pa.field("value_bool", pa.bool_()),  # Boolean
        pa.field("value_json", pa.string()),  # StructuredValue, arrays, geometry: JSON as received
    ]
)

_AFTER_TIME = list(SCHEMA)[1:]  # every column after the time
assert tuple(SCHEMA.names) == EXPORT_COLUMNS


class SampleStream:
    """Record batches in ``SCHEMA``; ``next_batch()`` is None at the end.

    Holds the seam's ``SampleBatches`` (a database cursor, and on PostgreSQL
    a pooled connection in a transaction) until ``close()``; use it as a
    context manager, from one thread at a time, never on the event loop."""

    def __init__(self) -> None:
        self._resources = ExitStack()
        self._next: Callable[[], pa.RecordBatch | None] = _nothing
        self.rows = 0

    def next_batch(self) -> pa.RecordBatch | None:
        batch = self._next()
        if batch is not None:
            self.rows += batch.num_rows
        return batch

    def close(self) -> None:
        self._next = _nothing
        self._resources.close()

    def __enter__(self) -> SampleStream:
        return self

    def __exit__(self, *exc_info) -> None:
        self.close()


def _nothing() -> None:
    return None


def open_export(store: Reader, query: ExportQuery) -> SampleStream:
    """Resolve the series and start the query; nothing is read yet beyond
    what the database needs to produce the first batch."""
    querier = store.querier()
    refs = querier.series(SeriesSelect(query.scope, query.entities, query.attrs))
    stream = SampleStream()
    if not refs:
        return stream
    sids = sorted({ref.sid for ref in refs})
    batches = stream._resources.enter_context(
        querier.export_batches(ExportRead(sids, query.time, BATCH_ROWS, WINDOW_ROWS))
    )
    stream._next = partial(_next_batch, batches)
    return stream


def _next_batch(batches: SampleBatches) -> pa.RecordBatch | None:
    columns = batches.next()
    return None if columns is None else _conform(columns)


def _conform(columns) -> pa.RecordBatch:
    """Columns as the database produced them → exactly ``SCHEMA``: naive UTC
    timestamps (or epoch microseconds) become UTC timestamps."""
    out = [columns[0].cast(pa.int64()).cast(UTC_MICROS)]
    out += [col.cast(field.type) for col, field in zip(columns[1:], _AFTER_TIME, strict=True)]
    return pa.RecordBatch.from_arrays(out, schema=SCHEMA)
