"""Stored samples as a stream of Arrow columns, for exports (``tsdb_service.faces.export``).

The export's one query is rendered here (``export_sql``: bound values only)
and run by each backend's querier (``Querier.export_batches``): DuckDB in
consecutive time windows on a private cursor, PostgreSQL through a
server-side cursor. ``SampleBatches`` is what crosses the seam: the columns
of ``EXPORT_COLUMNS``, a batch at a time, oldest sample first.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from contextlib import ExitStack

import pyarrow as pa

from tsdb_service.core.errors import Unavailable
from tsdb_service.core.model import Kind
from tsdb_service.core.query import TimeRange
from tsdb_service.storage.sql import Dialect, series_time_filter

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
# The Arrow types of the columns after ``time`` (rows a driver hands over as tuples).
AFTER_TIME_TYPES = (pa.string(),) * 5 + (pa.float64(), pa.string(), pa.bool_(), pa.string())
_NUMERIC = f"{int(Kind.NUMBER)}, {int(Kind.INTEGER)}"
_TEXTUAL = f"{int(Kind.TEXT)}, {int(Kind.DATETIME)}, {int(Kind.RELATIONSHIP)}"
_JSON = f"{int(Kind.STRUCTURED)}, {int(Kind.GEO)}"

Columns = list[pa.Array]


def export_sql(dialect: Dialect, sids: Sequence[int], time: TimeRange, time_expr: str) -> tuple[str, list]:
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


def rows_to_columns(rows: Sequence[tuple]) -> Columns:
    """Driver rows (time as epoch µs) → Arrow columns, one array per column."""
    columns = list(zip(*rows, strict=True))
    arrays = [pa.array(columns[0], type=pa.int64())]
    arrays += [pa.array(col, type=kind) for col, kind in zip(columns[1:], AFTER_TIME_TYPES, strict=True)]
    return arrays


class SampleBatches:
    """Batches of export columns (``EXPORT_COLUMNS``); ``next()`` is None at the end.

    Holds a database cursor (PostgreSQL: a pooled connection in one
    transaction, so the stream is one snapshot) from ``Querier.export_batches``
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
