"""Long windows over SQL: time buckets, state changes and spans (``read.buckets``).

One bucket query for both backends, rendered through the ``SqlDialect``:
per series and bucket, the count, sum, minimum and maximum of its numeric
samples, its first and last, each with its time, grouped in the database
in one statement for all the series (nothing per sample in Python).

The statement is built from *parts* of one row layout (``BUCKET_COLUMNS``),
each covering a time range, UNION ALLed and combined per (series, bucket):

* ``raw_part(dialect, sids, time, width, steps)``: the partial rows of the
  raw samples in ``time`` (``samples`` and, on DuckDB, ``samples_hot``);
* ``combine(dialect, parts)``: the parts' rows of the same bucket merged
  into one (count and sum added, the earliest minimum and maximum, the
  first of the earliest part and the last of the latest). Parts cover
  disjoint time ranges, so no two rows of a bucket share a first or last
  sample time;
* ``bucket_sql(dialect, ask)``: the query of a ``BucketRead``: where the
  width is made of whole minutes or hours, the window's whole hours and
  minutes come from the rollups (``storage.rollup_reads.bucket_part``, the same
  layout, exactly what their raw samples give) and only the edges from
  ``raw_part``, through ``combine``.

Invariants:

* a row's ``start`` is the bucket's start, epoch µs, aligned to the epoch
  (``core.buckets.bucket_start``), also for a bucket cut by the window;
* ties go to the earliest sample, then the lowest row id (``last``: the
  latest, then the highest row id): ``SqlDialect.time_of_min`` and friends,
  never the database's arbitrary pick among equal values;
* only numeric samples count (``NUMERIC_KINDS`` with a number; at a value
  path, the JSON numbers there); a bucket without one has no row.

State changes keep a sample when its value differs from the series'
previous sample in the window (``lag`` over (time, row id)), or it is the
window's first; the newest ``limit`` are kept, and one more tells that
older ones were left out.
"""

from __future__ import annotations

from collections.abc import Sequence
from datetime import timedelta

from tsdb_service.core import budget
from tsdb_service.core.query import TimeRange
from tsdb_service.read.buckets import (
    BucketRead,
    BucketReader,
    BucketRow,
    ChangesPage,
    ChangesRead,
    StateChange,
    TimedSample,
)
from tsdb_service.read.requests import SamplesIn
from tsdb_service.storage.rollup_reads import bucket_levels, bucket_part, expired_span_sql, split_window
from tsdb_service.storage.sql.dialect import (
    INTEGER_KIND,
    MAX_BIGINT,
    NUMERIC_KINDS,
    SqlDialect,
    rows_as,
    series_time_filter,
)
from tsdb_service.storage.sql.reads import SqlReads

# The layout of every part and of the answer (``BucketRow``).
BUCKET_COLUMNS = "sid, start, n, total, all_integer, min, min_t, max, max_t, first, first_t, last, last_t"
as_buckets = rows_as(BucketRow)
as_changes = rows_as(StateChange)
_MICRO = timedelta(microseconds=1)


def width_us(width: timedelta) -> int:
    return width // _MICRO


def _numbers(dialect: SqlDialect, steps: tuple[str | int, ...]) -> tuple[str, str, list]:
    """(the columns read, the select list ``v, i`` of each sample's number and
    whether it is an integer, their parameters); ``v`` is NULL for a sample
    that holds no number."""
    if not steps:
        numeric = f"kind IN ({NUMERIC_KINDS})"
        return "sid, rid, t, kind, num", f"CASE WHEN {numeric} THEN num END AS v, kind = {INTEGER_KIND} AS i", []
    path = dialect.json_path(steps)
    number, nparams = dialect.json_number("js", path)
    integer, iparams = dialect.json_is_integer("js", path)
    return "sid, rid, t, js", f"{number} AS v, {integer} AS i", [*nparams, *iparams]


def raw_part(
    dialect: SqlDialect,
    sids: Sequence[int],
    time: TimeRange,
    width: timedelta,
    steps: tuple[str | int, ...] = (),
    extreme_times: bool = True,
) -> tuple[str, list]:
    """The partial rows (``BUCKET_COLUMNS``) of the raw samples of ``sids`` in
    ``time`` (inclusive; an open end reads to the end), in buckets of ``width``;
    without ``extreme_times``, ``min_t`` and ``max_t`` are NULL."""
    d = dialect
    columns, values, vparams = _numbers(d, steps)
    where, wparams = series_time_filter(d, sids, time)
    w = width_us(width)
    key, kparams = d.bucket_index("t", "tu", w)
    start, sparams = d.bucket_start("b", w)
    inner = f"SELECT sid, rid, {d.epoch_us('t')} AS tu, t, {values} FROM {d.samples(columns)} WHERE {where}{d.fence}"
    value_key = f", {d.value_key('v')} AS vk" if extreme_times else ""
    keyed = f"SELECT sid, rid, tu, v, i, {key} AS b{value_key} FROM ({inner}) AS x WHERE v IS NOT NULL"
    min_t = d.time_of_min("v", "vk", "tu") if extreme_times else "CAST(NULL AS BIGINT)"
    max_t = d.time_of_max("v", "vk", "tu") if extreme_times else "CAST(NULL AS BIGINT)"
    sql = (
        f"SELECT sid, {start} AS start, count(*) AS n, sum(v) AS total, "
        "count(*) FILTER (WHERE i) = count(*) AS all_integer, "
        f"min(v) AS min, {min_t} AS min_t, max(v) AS max, {max_t} AS max_t, "
        f"{d.value_at_first('v', 'tu', 'rid')} AS first, min(tu) AS first_t, "
        f"{d.value_at_last('v', 'tu', 'rid')} AS last, max(tu) AS last_t "
        f"FROM ({keyed}) AS y GROUP BY sid, b"
    )
    # Placeholders in textual order: the bucket start, the bucket key, the
    # numbers, the WHERE.
    return sql, [*sparams, *kparams, *vparams, *wparams]


def combine(dialect: SqlDialect, parts: Sequence[tuple[str, list]]) -> tuple[str, list]:
    """Parts of disjoint time ranges in ``BUCKET_COLUMNS`` → one row per
    (series, bucket) in the same layout. One part is its own answer."""
    if len(parts) == 1:
        return parts[0]
    d = dialect
    union = " UNION ALL ".join(f"SELECT {BUCKET_COLUMNS} FROM ({sql}) AS p{i}" for i, (sql, _) in enumerate(parts))
    keyed = f"SELECT {BUCKET_COLUMNS}, {d.value_key('min')} AS min_k, {d.value_key('max')} AS max_k FROM ({union}) AS u"
    sql = (
        "SELECT sid, start, CAST(sum(n) AS BIGINT) AS n, sum(total) AS total, bool_and(all_integer) AS all_integer, "
        f"min(min) AS min, {d.time_of_min('min', 'min_k', 'min_t')} AS min_t, "
        f"max(max) AS max, {d.time_of_max('max', 'max_k', 'max_t')} AS max_t, "
        f"{d.value_at_first('first', 'first_t', '0')} AS first, min(first_t) AS first_t, "
        f"{d.value_at_last('last', 'last_t', '0')} AS last, max(last_t) AS last_t "
        f"FROM ({keyed}) AS k GROUP BY sid, start"
    )
    return sql, [value for _, params in parts for value in params]


def bucket_sql(dialect: SqlDialect, ask: BucketRead) -> tuple[str, list]:
    """The whole query of ``ask``, rows by series then bucket start: the
    window's whole hours and minutes from the rollups where the width is
    made of them (``storage.rollup_reads``: ``split_window``, ``bucket_part``),
    the rest from raw samples; a value path from raw samples only."""
    parts = []
    for piece in split_window(ask.time, bucket_levels(ask.width) if not ask.steps else ()):
        if piece.level is None:
            time = TimeRange(piece.start, piece.end)
            parts.append(raw_part(dialect, ask.sids, time, ask.width, ask.steps, ask.extreme_times))
        else:
            parts.append(bucket_part(dialect, piece.level, ask.sids, piece, ask.width, ask.extreme_times))
    sql, params = combine(dialect, parts)
    return f"SELECT {BUCKET_COLUMNS} FROM ({sql}) AS b ORDER BY sid, start", params


def _compared(dialect: SqlDialect, steps: tuple[str | int, ...]) -> tuple[list[str], list]:
    """What two samples must share to be the same state: the stored value's
    columns, or the JSON value at ``steps``."""
    if not steps:
        return ["kind", "num", "txt", "js"], []
    value, params = dialect.json_value("js", dialect.json_path(steps))
    return [value], params


def changes_sql(dialect: SqlDialect, ask: ChangesRead) -> tuple[str, list]:
    """The newest ``ask.limit + 1`` transitions, newest first, as
    (sid, time µs, kind, num, txt, js, the previous sample's time µs)."""
    d = dialect
    where, wparams = series_time_filter(d, ask.sids, ask.time)
    compared, cparams = _compared(d, ask.steps)
    window = "OVER (PARTITION BY sid ORDER BY t, rid)"
    values = ", ".join(f"{expr} AS c{i}" for i, expr in enumerate(compared))
    lags = ", ".join(f"lag(c{i}) {window} AS p{i}" for i in range(len(compared)))
    differs = " OR ".join(f"c{i} IS DISTINCT FROM p{i}" for i in range(len(compared)))
    inner = f"SELECT sid, rid, t, kind, num, txt, js, {values} FROM {d.samples('sid, rid, t, kind, num, txt, js')} "
    inner += f"WHERE {where}{d.fence}"
    mine = ", ".join(f"c{i}" for i in range(len(compared)))
    ranked = (
        f"SELECT sid, rid, t, kind, num, txt, js, {mine}, row_number() {window} AS rn, "
        f"lag(t) {window} AS before, {lags} FROM ({inner}) AS x"
    )
    p = d.placeholder
    sql = (
        f"SELECT sid, {d.epoch_us('t')}, kind, num, txt, js, {d.epoch_us('before')} FROM ({ranked}) AS y "
        f"WHERE rn = 1 OR {differs} ORDER BY t DESC, rid DESC, sid DESC LIMIT {p}"
    )
    return sql, [*cparams, *wparams, min(ask.limit + 1, MAX_BIGINT)]


def span_sql(dialect: SqlDialect, ask: SamplesIn) -> tuple[str, list]:
    d = dialect
    where, params = series_time_filter(d, ask.sids, ask.time)
    return f"SELECT {d.epoch_us('min(t)')}, {d.epoch_us('max(t)')} FROM {d.samples('sid, t')} WHERE {where}", params


def count_up_to_sql(dialect: SqlDialect, ask: SamplesIn, most: int) -> tuple[str, list]:
    """A count that stops reading at ``most`` rows (a LIMIT without ORDER BY)."""
    d = dialect
    where, params = series_time_filter(d, ask.sids, ask.time)
    return (
        f"SELECT count(*) FROM (SELECT 1 AS one FROM {d.samples('sid, t')} WHERE {where} LIMIT {d.placeholder}) AS c",
        [*params, max(0, min(most, MAX_BIGINT))],
    )


def samples_sql(dialect: SqlDialect, ask: SamplesIn, most: int) -> tuple[str, list]:
    d = dialect
    where, params = series_time_filter(d, ask.sids, ask.time)
    sql = (
        f"SELECT sid, {d.epoch_us('t')}, kind, num, txt, js FROM {d.samples('sid, rid, t, kind, num, txt, js')} "
        f"WHERE {where} ORDER BY sid, t, rid LIMIT {d.placeholder}"
    )
    return sql, [*params, max(0, min(most, MAX_BIGINT))]


class SqlBuckets(SqlReads, BucketReader):
    def buckets(self, ask: BucketRead) -> list[BucketRow]:
        """See ``BucketReader``: one statement (``bucket_sql``)."""
        if not ask.sids:
            return []
        sql, params = bucket_sql(self.dialect, ask)
        if budget.current() is not None:  # one row past the request's budget detects an overflow
            sql = f"{sql} LIMIT {self.dialect.placeholder}"
            params = [*params, budget.row_cap(MAX_BIGINT)]
        return as_buckets(self._fetch(sql, params))

    def state_changes(self, ask: ChangesRead) -> ChangesPage:
        """See ``BucketReader``: one statement (``changes_sql``)."""
        if not ask.sids or ask.limit < 1:
            return ChangesPage([], bool(ask.sids) and self._any(ask))
        rows = self._fetch(*changes_sql(self.dialect, ask))
        truncated = len(rows) > ask.limit
        kept = as_changes(rows[: ask.limit])
        kept.reverse()
        return ChangesPage(kept, truncated)

    def _any(self, ask: ChangesRead) -> bool:
        """Raw samples in the window (transitions are read from them only)."""
        return self._raw_span(SamplesIn(ask.sids, ask.time)) is not None

    def span(self, ask: SamplesIn) -> tuple[int, int] | None:
        """See ``BucketReader``: the raw samples' span, widened by the
        history rollups keep of samples retention deleted."""
        if not ask.sids:
            return None
        found = [s for s in (self._raw_span(ask), self._rolled_up_span(ask)) if s is not None]
        if not found:
            return None
        return min(lo for lo, _ in found), max(hi for _, hi in found)

    def _raw_span(self, ask: SamplesIn) -> tuple[int, int] | None:
        """The first and last raw sample times (``span_sql``)."""
        rows = self._fetch(*span_sql(self.dialect, ask))
        return (int(rows[0][0]), int(rows[0][1])) if rows and rows[0][0] is not None else None

    def _rolled_up_span(self, ask: SamplesIn) -> tuple[int, int] | None:
        """The span of what only rollups keep (``storage.rollup_reads.expired_span_sql``);
        nothing to read until retention has deleted raw samples."""
        if not self.raw_expired():
            return None
        rows = self._fetch(*expired_span_sql(self.dialect, ask.sids, ask.time))
        return (int(rows[0][0]), int(rows[0][1])) if rows and rows[0][0] is not None else None

    def count_up_to(self, ask: SamplesIn, most: int) -> int:
        """See ``BucketReader``. A window holding history only rollups keep
        (retention deleted its raw samples) counts as ``most``: raw samples
        cannot draw it whole, its buckets can."""
        if not ask.sids or most <= 0:
            return 0
        rows = self._fetch(*count_up_to_sql(self.dialect, ask, most))
        counted = int(rows[0][0]) if rows else 0
        if counted < most and self._rolled_up_span(ask) is not None:
            return most
        return counted

    def samples(self, ask: SamplesIn, most: int) -> list[TimedSample]:
        if not ask.sids or most <= 0:
            return []
        return self._fetch(*samples_sql(self.dialect, ask, most))
