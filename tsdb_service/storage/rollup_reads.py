"""Reading rollups: which parts of a window whole minutes and hours answer,
and the SQL that reads them (``storage.rollups`` defines the levels and
keeps them).

A window splits (``split_window``) into pieces: whole buckets of the
coarsest level that fits, finer levels at its edges, raw samples at the
very ends; the QuantumLeap aggregations (``aggregate_part``, in
``storage.sql.aggregate``) and the bucket query that draws (``bucket_part``,
in ``storage.sql.buckets``) read each piece from its own table and combine
them. What only rollups hold after retention is seen by ``rolled_up_count``
and ``expired_span_sql``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta

from tsdb_service.core.buckets import epoch_micros, served_by
from tsdb_service.core.query import AggrMethod, AggrPeriod, TimeRange
from tsdb_service.storage.rollups import (
    COLS,
    COMPLETE,
    EXPIRED,
    HOUR,
    LEVELS,
    MINUTE,
    Level,
    at_max,
    at_min,
    before,
    pick,
    within,
)
from tsdb_service.storage.sql.dialect import SqlDialect

_US = timedelta(microseconds=1)
_EPOCH = datetime(1970, 1, 1, tzinfo=UTC)


def _moment(micros: int) -> datetime:
    return _EPOCH + timedelta(microseconds=micros)


@dataclass(frozen=True, slots=True)
class Piece:
    """A part of a window: buckets of ``level`` with ``start <= bucket <
    end``, or (``level`` None) raw samples in ``[start, end]``; None: open."""

    level: Level | None
    start: datetime | None
    end: datetime | None


def split_window(time: TimeRange, levels: Sequence[Level]) -> list[Piece]:
    """``time`` (inclusive, to the µs) as the whole buckets of the coarsest
    of ``levels`` inside it, its edges likewise with the next level, and what
    is left as raw samples."""
    if not levels:
        return [Piece(None, time.start, time.end)]
    level, finer = levels[0], levels[1:]
    size = level.width // _US
    first = None if time.start is None else -(-epoch_micros(time.start) // size) * size  # first whole bucket
    past = None if time.end is None else (epoch_micros(time.end) + 1) // size * size  # end of the last whole one
    if first is not None and past is not None and first >= past:
        return split_window(time, finer)
    out = []
    if time.start is not None and first is not None and epoch_micros(time.start) < first:
        out += split_window(TimeRange(time.start, _moment(first - 1)), finer)
    out.append(Piece(level, None if first is None else _moment(first), None if past is None else _moment(past)))
    if time.end is not None and past is not None and past <= epoch_micros(time.end):
        out += split_window(TimeRange(_moment(past), time.end), finer)
    return out


# Aggregation periods made of whole buckets of each level, coarsest first.
PERIOD_LEVELS = {
    None: (HOUR, MINUTE),
    AggrPeriod.YEAR: (HOUR, MINUTE),
    AggrPeriod.MONTH: (HOUR, MINUTE),
    AggrPeriod.DAY: (HOUR, MINUTE),
    AggrPeriod.HOUR: (HOUR, MINUTE),
    AggrPeriod.MINUTE: (MINUTE,),
}


def aggregate_part(
    d: SqlDialect, number: int, sids: Sequence[int], piece: Piece, method: AggrMethod, period: AggrPeriod | None
) -> tuple[str, list]:
    """A branch's aggregate rows from ``piece``'s level, in the raw
    aggregation's layout (branch, sid, ISO bucket | NULL, n_present,
    n_numeric, value, all_integer)."""
    assert piece.level is not None
    fn = {
        AggrMethod.SUM: "sum(num_sum)",
        AggrMethod.AVG: "sum(num_sum)",
        AggrMethod.MIN: "min(num_min)",
        AggrMethod.MAX: "max(num_max)",
    }.get(method, "NULL")
    trunc = d.date_trunc(period.value, "bucket") if period is not None else None
    where, params = within(d, sids, piece.start, before(piece.end))
    sql = (
        f"SELECT {number} AS branch, sid, {d.iso_ms(trunc) if trunc else 'NULL'} AS bucket, "
        "CAST(sum(n_present) AS BIGINT) AS n_present, CAST(sum(n_numeric) AS BIGINT) AS n_numeric, "
        f"{fn} AS value, CASE WHEN sum(n_numeric) > 0 THEN sum(n_integer) = sum(n_numeric) END AS all_integer "
        f"FROM {piece.level.view} WHERE {where} GROUP BY sid{', ' + trunc if trunc else ''}"
    )
    return sql, params


def bucket_levels(width: timedelta) -> tuple[Level, ...]:
    """The levels whose whole buckets make buckets of ``width``, coarsest
    first (``core.buckets.served_by``): what ``split_window`` takes for a
    ``read.buckets.BucketRead``."""
    return tuple(level for level in reversed(LEVELS) if served_by(width, level.width))


def bucket_part(
    d: SqlDialect, level: Level, sids: Sequence[int], piece: Piece, width: timedelta, extreme_times: bool = True
) -> tuple[str, list]:
    """The rows of ``read.buckets.BucketRow`` (sid, start µs, n, total,
    all_integer, min, min_t, max, max_t, first, first_t, last, last_t) of
    the numeric samples in ``level``'s whole buckets of ``piece`` (``start
    <= bucket < end``), grouped into buckets of ``width`` (a multiple of the
    level's, from the epoch): exactly what the raw samples of that time give
    (``storage.sql.buckets.raw_part``), ties included: one part of the
    bucket query, combined with the raw parts of the window's edges. Without
    ``extreme_times``, ``min_t`` and ``max_t`` are NULL (``BucketRead``)."""
    w = width // _US
    where, params = within(d, sids, piece.start, before(piece.end))
    where += " AND n_numeric > 0"
    inner = f"SELECT {COLS}, {d.epoch_us('bucket')} AS bu FROM {level.view} WHERE {where}{d.fence}"
    start = f"(bu - mod(mod(bu, {w}) + {w}, {w}))"
    only = "num_min IS NOT NULL"
    min_t = at_min(d, "num_min", "min_us", only) if extreme_times else "CAST(NULL AS BIGINT)"
    max_t = at_max(d, "num_max", "max_us", only) if extreme_times else "CAST(NULL AS BIGINT)"
    sql = (
        f"SELECT sid, {start} AS start, CAST(sum(n_numeric) AS BIGINT) AS n, sum(num_sum) AS total, "
        "sum(n_integer) = sum(n_numeric) AS all_integer, "
        f"min(num_min) AS min, {min_t} AS min_t, max(num_max) AS max, {max_t} AS max_t, "
        f"{pick(d, 'num_first', 'first_us', 'first_rid', 'num_first IS NOT NULL', last=False)} AS first, "
        "min(first_us) FILTER (WHERE num_first IS NOT NULL) AS first_t, "
        f"{pick(d, 'num_last', 'last_us', 'last_rid', 'num_last IS NOT NULL', last=True)} AS last, "
        "max(last_us) FILTER (WHERE num_last IS NOT NULL) AS last_t "
        f"FROM ({inner}) AS r GROUP BY sid, {start}"
    )
    return sql, params


def rolled_up_count(querier, sids: Sequence[int], time: TimeRange) -> int:
    """Buckets of ``sids`` wholly inside ``time`` that hold history retention
    deleted from raw: what a delete finds to delete where no raw sample is
    left (a delete drops them; buckets it only cuts stay as they are)."""
    d = querier.dialect
    parts, params = [], []
    for level in LEVELS:
        last = None if time.end is None else time.end - level.width + _US  # the bucket ends inside
        where, wparams = within(d, sids, time.start, last)
        parts.append(f"SELECT count(*) AS n FROM {level.view} r WHERE {where} AND NOT {COMPLETE}")
        params += wparams
    rows = querier._fetch(f"SELECT sum(n) FROM ({' UNION ALL '.join(parts)}) AS c", params)
    return int(rows[0][0] or 0) if rows else 0


def expired_span_sql(d: SqlDialect, sids: Sequence[int], time: TimeRange) -> tuple[str, list]:
    """SELECT min(lo), max(hi), epoch µs, clipped to ``time`` (inclusive;
    None: open): the first and last number (a bucket's edges where it holds
    none) of the rollup rows of ``sids`` meeting ``time`` that hold samples
    retention deleted (incomplete buckets, either level). NULLs: none. What
    raw samples no longer show of a window: its span, and whether raw
    samples alone can draw it (``storage.sql.buckets``).

    Only the earliest and the latest such bucket are read: PostgreSQL probes
    them per series that retention reached, two index probes a level;
    DuckDB (which turns such probes into joins over every row) finds the
    two buckets with one grouped scan, then reads their rows."""
    p = d.placeholder
    los, his, bparams = [], [], []
    for level in LEVELS:
        bu, size = d.epoch_us("r.bucket"), level.width // _US
        lo, hi = f"coalesce(r.first_us, {bu})", f"coalesce(r.last_us, {bu} + {size - 1})"
        bounds, params = "r.sid = e.sid AND r.n_present > 0 AND r.bucket <= e.upto", []
        if time.start is not None:
            bounds += f" AND r.bucket >= {p}"
            params.append(d.time_value(time.start - level.width + _US))
        if time.end is not None:
            bounds += f" AND r.bucket <= {p}"
            params.append(d.time_value(time.end))
        if d.name == "duckdb":
            sid_where, sid_params = d.sid_filter(sids)
            rows = f"FROM {level.view} r JOIN {EXPIRED} e ON {bounds} WHERE r.{sid_where}"
            ends = f"(SELECT min(r.bucket) AS b0, max(r.bucket) AS b1 {rows})"
            los.append(f"(SELECT min({lo}) {rows} AND r.bucket = (SELECT b0 FROM {ends} AS k))")
            his.append(f"(SELECT max({hi}) {rows} AND r.bucket = (SELECT b1 FROM {ends} AS k))")
            params = [*params, *sid_params] * 2
        else:
            los.append(f"(SELECT {lo} FROM {level.view} r WHERE {bounds} ORDER BY r.bucket, 1 LIMIT 1)")
            his.append(f"(SELECT {hi} FROM {level.view} r WHERE {bounds} ORDER BY r.bucket DESC, 1 DESC LIMIT 1)")
        bparams.append(params)
    lo, hi = f"least({', '.join(los)})", f"greatest({', '.join(his)})"  # both ignore NULLs
    if time.start is not None:
        lo = f"greatest({lo}, {epoch_micros(time.start)})"
    if time.end is not None:
        hi = f"least({hi}, {epoch_micros(time.end)})"
    # Placeholders in textual order: the levels' lo parts, their hi parts (then, on PostgreSQL, the series).
    params = [v for ps in bparams for v in ps] * 2
    if d.name == "duckdb":
        return f"SELECT {lo}, {hi}", params
    where, wparams = d.sid_filter(sids)
    sql = f"SELECT min(lo), max(hi) FROM (SELECT {lo} AS lo, {hi} AS hi FROM {EXPIRED} e WHERE {where}) AS x"
    return sql, [*params, *wparams]
