"""Whole-store reads over SQL: the export's query, counts, every sample for a copy.

The export's one query is rendered here (``export_sql``: bound values only)
and run by each backend's querier (``BulkReader.export_batches``): DuckDB in
consecutive time windows on a private cursor, PostgreSQL through a
server-side cursor.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from datetime import datetime

import pyarrow as pa

from tsdb_service.core.model import Kind
from tsdb_service.core.query import StoredSample, TimeRange
from tsdb_service.read.bulk import Columns
from tsdb_service.storage.columns import SAMPLE_COLUMNS
from tsdb_service.storage.sql.dialect import SqlDialect, rows_as, series_time_filter
from tsdb_service.storage.sql.reads import SqlReads

# The Arrow types of the columns after ``time`` (rows a driver hands over as tuples).
AFTER_TIME_TYPES = (pa.string(),) * 5 + (pa.float64(), pa.string(), pa.bool_(), pa.string())
_NUMERIC = f"{int(Kind.NUMBER)}, {int(Kind.INTEGER)}"
_TEXTUAL = f"{int(Kind.TEXT)}, {int(Kind.DATETIME)}, {int(Kind.RELATIONSHIP)}"
_JSON = f"{int(Kind.STRUCTURED)}, {int(Kind.GEO)}"


def export_sql(dialect: SqlDialect, sids: Sequence[int], time: TimeRange, time_expr: str) -> tuple[str, list]:
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


_STORED_COLUMNS = ", ".join(SAMPLE_COLUMNS)
as_stored = rows_as(StoredSample)


class SqlBulk(SqlReads):
    def sample_counts(self) -> dict[str, int]:
        rows = self._fetch(
            f"SELECT s.tenant, count(*) FROM (SELECT sid FROM {self.dialect.samples('sid')}) x "
            "JOIN series s ON s.sid = x.sid "
            "GROUP BY s.tenant",
            [],
        )
        return {tenant: int(n) for tenant, n in rows}

    def type_counts(self, before: datetime | None = None) -> dict[tuple[str, str], tuple[int, int]]:
        where, params = ("", []) if before is None else (f" WHERE t < {self.dialect.placeholder}", [before])
        rows = self._fetch(
            f"SELECT s.tenant, s.entity_type, count(DISTINCT x.rid), count(*) "
            f"FROM (SELECT sid, rid FROM {self.dialect.samples('sid, rid, t')}{where}) x "
            "JOIN series s ON s.sid = x.sid "
            "GROUP BY s.tenant, s.entity_type",
            [self.dialect.time_value(p) for p in params],
        )
        return {(tenant, etype): (int(n_rows), int(n)) for tenant, etype, n_rows, n in rows}

    def stored_samples(self, batch_rows: int) -> Iterator[list[StoredSample]]:
        sql = f"SELECT {_STORED_COLUMNS} FROM {self.dialect.samples(_STORED_COLUMNS + ', iid')} ORDER BY rid, iid"
        for rows in self._batches(sql, [], batch_rows):
            yield as_stored(rows)
