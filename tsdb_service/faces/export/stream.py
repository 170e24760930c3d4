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

With a bucket width (``ExportQuery.bucket``) the rows are the database's
time buckets instead (``BucketReader.buckets``, in ``BUCKET_SCHEMA``): one
per series and bucket holding numbers, ordered by bucket, then entity and
attribute, read a piece of the window at a time (at most ``BATCH_ROWS``
buckets), skipping stretches without samples.

Every call here blocks: callers run it in a thread, never on the event loop.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from contextlib import ExitStack
from datetime import UTC, datetime, timedelta
from functools import partial

import pyarrow as pa

from tsdb_service.core.buckets import bucket_start
from tsdb_service.core.query import SeriesRef, TimeRange
from tsdb_service.faces.export.query import ExportQuery
from tsdb_service.read import Querier, Reader
from tsdb_service.read.buckets import BucketRead, BucketRow
from tsdb_service.read.bulk import EXPORT_COLUMNS, SampleBatches
from tsdb_service.read.requests import ExportRead, SamplesIn, SeriesSelect

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

# ``bucket=``: one row per series and bucket (docs/operations.md, "Export").
BUCKET_SCHEMA = pa.schema(
    [
        pa.field("time", UTC_MICROS, nullable=False),  # the bucket's start
        pa.field("entity_id", pa.string(), nullable=False),
        pa.field("entity_type", pa.string(), nullable=False),
        pa.field("service_path", pa.string(), nullable=False),
        pa.field("attribute", pa.string(), nullable=False),
        pa.field("n", pa.int64(), nullable=False),  # numeric samples in the bucket
        pa.field("avg", pa.float64(), nullable=False),
        pa.field("min", pa.float64(), nullable=False),
        pa.field("max", pa.float64(), nullable=False),
        pa.field("first", pa.float64(), nullable=False),
        pa.field("last", pa.float64(), nullable=False),
    ]
)
_EPOCH = datetime(1970, 1, 1, tzinfo=UTC)
_US = timedelta(microseconds=1)


class SampleStream:
    """Record batches in ``SCHEMA``; ``next_batch()`` is None at the end.

    Holds the seam's ``SampleBatches`` (a database cursor, and on PostgreSQL
    a pooled connection in a transaction) until ``close()``; use it as a
    context manager, from one thread at a time, never on the event loop."""

    def __init__(self, schema: pa.Schema = SCHEMA) -> None:
        self._resources = ExitStack()
        self._next: Callable[[], pa.RecordBatch | None] = _nothing
        self.rows = 0
        self.schema = schema

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
    if query.bucket is not None:
        stream = SampleStream(BUCKET_SCHEMA)
        if refs:
            stream._next = partial(next, _bucket_batches(querier, refs, query.time, query.bucket), None)
        return stream
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


def _bucket_batches(
    querier: Querier, refs: Sequence[SeriesRef], time: TimeRange, width: timedelta
) -> Iterator[pa.RecordBatch]:
    """The buckets of ``refs`` in ``time``, a piece of the window at a time:
    each piece at most ``BATCH_ROWS`` buckets (series x buckets), starting at
    the first sample after the last piece (``span``)."""
    sids = sorted({ref.sid for ref in refs})
    by_sid = {ref.sid: ref for ref in refs}
    per_piece = width * max(1, BATCH_ROWS // len(sids))
    end = time.end
    start = time.start
    while True:
        found = querier.span(SamplesIn(sids, TimeRange(start, end)))
        if found is None:
            return
        first = bucket_start(_EPOCH + found[0] * _US, width)
        stop = first + per_piece - _US
        last = _EPOCH + found[1] * _US
        if stop >= last:
            stop = last
        piece = TimeRange(first if start is None else max(first, start), stop)
        rows = querier.buckets(BucketRead(sids, piece, width, extreme_times=False))
        if rows:
            yield _bucket_batch(rows, by_sid)
        if stop >= last:
            return
        start = stop + _US


def _bucket_batch(rows: list[BucketRow], by_sid: dict[int, SeriesRef]) -> pa.RecordBatch:
    def order(row: BucketRow) -> tuple:
        ref = by_sid[row.sid]
        return (row.start, ref.entity_type, ref.entity_id, ref.attr, ref.service_path)

    rows = sorted(rows, key=order)
    refs = [by_sid[row.sid] for row in rows]
    columns = [
        pa.array([row.start for row in rows], type=pa.int64()).cast(UTC_MICROS),
        pa.array([ref.entity_id for ref in refs], type=pa.string()),
        pa.array([ref.entity_type for ref in refs], type=pa.string()),
        pa.array([ref.service_path for ref in refs], type=pa.string()),
        pa.array([ref.attr for ref in refs], type=pa.string()),
        pa.array([row.n for row in rows], type=pa.int64()),
        pa.array([row.total / row.n for row in rows], type=pa.float64()),
        pa.array([row.min for row in rows], type=pa.float64()),
        pa.array([row.max for row in rows], type=pa.float64()),
        pa.array([row.first for row in rows], type=pa.float64()),
        pa.array([row.last for row in rows], type=pa.float64()),
    ]
    return pa.RecordBatch.from_arrays(columns, schema=BUCKET_SCHEMA)
