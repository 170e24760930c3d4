"""The selected samples as a stream of Arrow record batches, on both backends.

Series are resolved on the querier's catalog, exactly as history queries
resolve them; samples are then read by series id with the shared renderer's
filter (``storage.sql.series_time_filter``: bound values only) and joined
with ``series`` for the names. Rows come oldest first (time, then the
notification, then the series), ``BATCH_ROWS`` at a time, so memory stays
bounded whatever the export's size:

* DuckDB hands its result over as Arrow batches (``to_arrow_reader``) on a
  private cursor, one time window of about ``WINDOW_ROWS`` samples at a
  time (DuckDB sorts in memory);
* PostgreSQL reads through a server-side cursor, and each ``fetchmany`` is
  turned into one record batch (times as epoch microseconds, so no Python
  ``datetime`` per row).

Every call here blocks: callers run it in a thread, never on the event loop.
"""

from __future__ import annotations

from contextlib import ExitStack
from datetime import UTC, datetime, timedelta
from typing import TYPE_CHECKING

import pyarrow as pa

from ..errors import Unavailable
from ..model import Kind
from ..query import TimeRange
from ..storage.sql import series_time_filter
from .query import ExportQuery

if TYPE_CHECKING:
    from ..storage.base import Store

BATCH_ROWS = 131_072
WINDOW_ROWS = 1_000_000  # DuckDB: samples sorted at once (see _start_duckdb)
_EPOCH = datetime(1970, 1, 1, tzinfo=UTC)
UTC_MICROS = pa.timestamp("us", tz="UTC")

# The export layout (README, "Export"). Exactly one value column is set per
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
_NUMERIC = f"{int(Kind.NUMBER)}, {int(Kind.INTEGER)}"
_TEXTUAL = f"{int(Kind.TEXT)}, {int(Kind.DATETIME)}, {int(Kind.RELATIONSHIP)}"
_JSON = f"{int(Kind.STRUCTURED)}, {int(Kind.GEO)}"


def export_sql(dialect, sids, time, time_expr: str) -> tuple[str, list]:
    """The export's one query: our own text, the request only as bound values."""
    where, params = series_time_filter(dialect, sids, time)
    samples = dialect.samples("sid, rid, t, kind, atype, num, txt, js")
    sql = (
        f"SELECT {time_expr} AS time, s.entity_id, s.entity_type, s.service_path, s.attr AS attribute, "
        "x.atype AS ngsi_type, "
        f"CASE WHEN x.kind IN ({_NUMERIC}) THEN x.num END AS value_number, "
        f"CASE WHEN x.kind IN ({_TEXTUAL}) THEN x.txt END AS value_text, "
        f"CASE WHEN x.kind = {int(Kind.BOOLEAN)} THEN x.num <> 0 END AS value_bool, "
        f"CASE WHEN x.kind IN ({_JSON}) THEN x.js END AS value_json "
        f"FROM (SELECT sid, rid, t, kind, atype, num, txt, js FROM {samples} WHERE {where}) x "
        "JOIN series s ON s.sid = x.sid ORDER BY x.t, x.rid, x.sid"
    )
    return sql, params


class SampleStream:
    """Record batches in ``SCHEMA``; ``next_batch()`` is None at the end.

    Holds a database cursor (and on PostgreSQL a pooled connection in a
    transaction) until ``close()``; use it as a context manager."""

    def __init__(self) -> None:
        self._resources = ExitStack()
        self._next = _nothing
        self.rows = 0

    def next_batch(self) -> pa.RecordBatch | None:
        try:
            batch = self._next()
        except Exception as exc:
            if isinstance(exc, Unavailable) or not _is_database_error(exc):
                raise
            raise Unavailable(f"the database is not available: {exc}") from None
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


def _is_database_error(exc: Exception) -> bool:
    module = type(exc).__module__ or ""
    return module.startswith(("duckdb", "psycopg"))


def open_export(store: Store, query: ExportQuery) -> SampleStream:
    """Resolve the series and start the query; nothing is read yet beyond
    what the database needs to produce the first batch."""
    querier = store.querier()
    refs = querier.series(query.scope, query.entities, query.attrs)
    stream = SampleStream()
    if not refs:
        return stream
    sids = sorted({ref.sid for ref in refs})
    try:
        if store.backend == "postgresql":
            _start_postgres(stream, store, querier.dialect, sids, query)
        else:
            _start_duckdb(stream, store, querier.dialect, sids, query)
    except Exception:
        stream.close()
        raise
    return stream


def _start_duckdb(stream: SampleStream, store, dialect, sids, query: ExportQuery) -> None:
    """DuckDB sorts a result in memory up to its (machine-wide) memory
    limit, so the selection is read as consecutive time windows of about
    ``WINDOW_ROWS`` samples each (split evenly over its time span), each
    sorted on its own: memory follows the window, not the export."""
    import duckdb

    try:
        cursor = store.cursor().cursor()  # private: the thread's cursor may be in use
    except duckdb.ConnectionException as exc:
        raise Unavailable(f"the database is not available: {exc}") from None
    stream._resources.callback(cursor.close)
    windows = iter(_time_windows(cursor, dialect, sids, query.time))
    reader = None

    def read() -> pa.RecordBatch | None:
        nonlocal reader
        while True:
            if reader is None:
                window = next(windows, None)
                if window is None:
                    return None
                sql, params = export_sql(dialect, sids, window, "x.t")
                reader = cursor.execute(sql, params).to_arrow_reader(BATCH_ROWS)
            try:
                return _conform(reader.read_next_batch().columns)
            except StopIteration:
                reader = None

    stream._next = read


def _time_windows(cursor, dialect, sids, time: TimeRange) -> list[TimeRange]:
    """Inclusive windows covering the selection's samples, one per
    ``WINDOW_ROWS`` of them (times are whole microseconds, so a window ending
    1 µs before the next one starts leaves no gap)."""
    where, params = series_time_filter(dialect, sids, time)
    first, last, count = cursor.execute(
        f"SELECT {dialect.epoch_us('min(t)')}, {dialect.epoch_us('max(t)')}, count(*) "
        f"FROM {dialect.samples('sid, t')} WHERE {where}",
        params,
    ).fetchone()
    if not count:
        return []
    pieces = max(1, -(-count // WINDOW_ROWS))
    step = -(-(last - first + 1) // pieces)
    return [TimeRange(_utc(start), _utc(min(start + step - 1, last))) for start in range(first, last + 1, step)]


def _utc(micros: int) -> datetime:
    return _EPOCH + timedelta(microseconds=micros)


def _start_postgres(stream: SampleStream, store, dialect, sids, query: ExportQuery) -> None:
    sql, params = export_sql(dialect, sids, query.time, dialect.epoch_us("x.t"))
    res = stream._resources
    conn = res.enter_context(store.connection())
    res.enter_context(conn.transaction())  # a server-side cursor lives in a transaction
    cursor = res.enter_context(conn.cursor(name="tsdb_export"))
    cursor.execute(sql, params)

    def read() -> pa.RecordBatch | None:
        rows = cursor.fetchmany(BATCH_ROWS)
        if not rows:
            return None
        columns = list(zip(*rows, strict=True))
        arrays = [pa.array(columns[0], type=pa.int64())]
        arrays += [pa.array(col, type=field.type) for col, field in zip(columns[1:], _AFTER_TIME, strict=True)]
        return _conform(arrays)

    stream._next = read


def _conform(columns) -> pa.RecordBatch:
    """Columns as the database produced them → exactly ``SCHEMA``: naive UTC
    timestamps (or epoch microseconds) become UTC timestamps."""
    out = [columns[0].cast(pa.int64()).cast(UTC_MICROS)]
    out += [col.cast(field.type) for col, field in zip(columns[1:], _AFTER_TIME, strict=True)]
    return pa.RecordBatch.from_arrays(out, schema=SCHEMA)
