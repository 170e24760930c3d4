"""Rebuilding and checking rollups against raw samples (``tsdb-service rollups``).

Rollups are kept exact by the write path (``storage.rollups``); these are
for when something else touched the tables: a bulk load straight into
``samples`` on DuckDB (PostgreSQL's trigger folds those too), rows deleted
or changed by hand, a restored partial backup.

* ``rebuild``: recomputes, from raw samples, every bucket of the series in
  a window that raw samples can still answer for (a *complete* bucket: none
  of its samples deleted by retention), including buckets that have raw
  samples but no rollup row. Buckets retention has emptied or partly emptied
  keep their rollups, unless ``drop_expired`` (then they hold what is left
  of raw, and history only rollups held is gone). It works in chunks of
  whole hours and groups of series, each one transaction (the store's
  ``rewrite_rollups``), so a rebuild of years never holds one huge
  transaction; with the service running (PostgreSQL), writes go on.
* ``check``: compares the rollups of a random sample of buckets with what
  their raw samples give, field by field (sums to a relative 1e-9: the
  order of additions differs), and lists every difference. Incomplete
  buckets are skipped: their rollups rightly hold more than raw.
* ``expired_history`` / ``put_expired_history``: what only rollups hold (the
  incomplete buckets of each series retention reached, combined per bucket,
  with its ``rollups_expired`` mark), read from one store in pages and
  written into another (``tsdb-service copy``): each page replaces the
  target's rows of its buckets, which then hold what the copied raw samples
  rolled up, so running it again changes nothing.
"""

from __future__ import annotations

import math
import random
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime, timedelta

from tsdb_service.core.buckets import bucket_start
from tsdb_service.core.query import TimeRange
from tsdb_service.storage.rollups import (
    COLS,
    COLUMNS,
    EXPIRED,
    HOT,
    HOUR,
    LEVELS,
    OPEN,
    Level,
    Redo,
    combine_partials,
    lock_statements,
    recompute_statements,
    samples_partials,
)
from tsdb_service.storage.sql.dialect import SqlDialect

CHUNK = timedelta(days=1)
SERIES_PER_CHUNK = 256
_US = timedelta(microseconds=1)
_SUM_TOLERANCE = 1e-9

Fetch = Callable[[str, list], list[tuple]]


@dataclass
class RebuildReport:
    series: int = 0
    transactions: int = 0
    buckets: int = 0  # minute and hour buckets recomputed (or dropped)
    start: datetime | None = None
    end: datetime | None = None


@dataclass(frozen=True, slots=True)
class Difference:
    level: str
    sid: int
    bucket: datetime
    column: str  # a rollup column, or "row" when one side has none
    rollup: object
    raw: object


@dataclass
class CheckReport:
    buckets: int = 0  # compared
    incomplete: int = 0  # skipped: retention deleted some of their samples
    differences: list[Difference] = field(default_factory=list)


def _as_utc(moment: datetime) -> datetime:
    """A timestamp column's naive UTC value as an aware datetime."""
    return moment.replace(tzinfo=UTC) if moment.tzinfo is None else moment


def span(fetch: Fetch, d: SqlDialect, sids: Sequence[int], time: TimeRange) -> tuple[datetime, datetime] | None:
    """The hours of ``time`` (defaulting to everything) holding raw samples
    or rollups of ``sids``: [first hour, end of the last)."""
    where, params = d.sid_filter(sids)
    found = [fetch(f"SELECT min(t), max(t) FROM {d.samples('sid, t')} WHERE {where}", params)[0]]
    for level in LEVELS:
        found.append(fetch(f"SELECT min(bucket), max(bucket) FROM {level.view} WHERE {where}", list(params))[0])
    lows = [_as_utc(row[0]) for row in found if row[0] is not None]
    highs = [_as_utc(row[1]) for row in found if row[1] is not None]
    if not lows:
        return None
    start = max(min(lows), time.start) if time.start is not None else min(lows)
    end = min(max(highs), time.end) if time.end is not None else max(highs)
    if start > end:
        return None
    return bucket_start(start, HOUR.width), bucket_start(end, HOUR.width) + HOUR.width


def rebuild(
    store,
    sids: Sequence[int],
    time: TimeRange = OPEN,
    *,
    drop_expired: bool = False,
    progress: Callable[[RebuildReport], None] | None = None,
) -> RebuildReport:
    """Recompute the rollups of ``sids`` over ``time`` from raw (see the
    module). Whole hours: a bucket ``time`` cuts is recomputed whole."""
    store.sync()
    querier = store.querier()
    d = querier.dialect
    report = RebuildReport(series=len(sids))
    found = span(querier._fetch, d, sids, time) if sids else None
    if found is None:
        return report
    report.start, report.end = found
    for i in range(0, len(sids), SERIES_PER_CHUNK):
        group = list(sids[i : i + SERIES_PER_CHUNK])
        at = found[0]
        while at < found[1]:
            upto = min(at + CHUNK, found[1])
            redo = Redo(group, TimeRange(at, upto - _US), every=drop_expired, from_raw=True)
            before, after = recompute_statements(d, redo)
            rows = store.rewrite_rollups([*before, *after, ("SELECT count(*) FROM rollups_redo", [])])
            report.transactions += 1
            report.buckets += int(rows[0][0]) if rows else 0
            if progress is not None:
                progress(report)
            at = upto
    return report


def check(
    store,
    sids: Sequence[int],
    time: TimeRange = OPEN,
    *,
    samples: int = 1000,
    seed: int | None = None,
) -> CheckReport:
    """Compare about ``samples`` buckets of ``sids`` in ``time`` (half of them
    buckets rollups hold, half picked uniformly in the window, per level)."""
    store.sync()
    querier = store.querier()
    fetch, d = querier._fetch, querier.dialect
    report = CheckReport()
    found = span(fetch, d, sids, time) if sids else None
    if found is None:
        return report
    rng = random.Random(seed)
    expired = _expired(fetch, d, sids)
    per_level = max(1, samples // (2 * len(LEVELS)))
    for level in LEVELS:
        keys = _sample_keys(fetch, d, level, sids, found, per_level, rng)
        complete = [(sid, b) for sid, b in keys if sid not in expired or b > expired[sid]]
        report.incomplete += len(keys) - len(complete)
        report.buckets += len(complete)
        if complete:
            report.differences += _compare(fetch, d, level, complete)
    return report


def _expired(fetch: Fetch, d: SqlDialect, sids: Sequence[int]) -> dict[int, datetime]:
    where, params = d.sid_filter(sids)
    return {sid: _as_utc(upto) for sid, upto in fetch(f"SELECT sid, upto FROM {EXPIRED} WHERE {where}", params)}


def _sample_keys(
    fetch: Fetch,
    d: SqlDialect,
    level: Level,
    sids: Sequence[int],
    window: tuple[datetime, datetime],
    n: int,
    rng: random.Random,
) -> list[tuple[int, datetime]]:
    """(sid, bucket): ``n`` among the rollup rows in ``window``, and ``n``
    uniformly at random (most of them in buckets raw holds, where data is
    dense; empty on both sides counts as agreeing)."""
    p = d.placeholder
    where, params = d.sid_filter(sids)
    held = fetch(
        f"SELECT sid, bucket FROM (SELECT DISTINCT sid, bucket FROM {level.view} WHERE {where} "
        f"AND bucket >= {p} AND bucket < {p}) AS k ORDER BY random() LIMIT {p}",
        [*params, d.time_value(window[0]), d.time_value(window[1]), n],
    )
    keys = {(sid, _as_utc(bucket)) for sid, bucket in held}
    buckets = int((window[1] - window[0]) / level.width)
    for _ in range(n):
        keys.add((rng.choice(list(sids)), window[0] + level.width * rng.randrange(max(1, buckets))))
    return sorted(keys)


def _compare(fetch: Fetch, d: SqlDialect, level: Level, keys: list[tuple[int, datetime]]) -> list[Difference]:
    p = d.placeholder
    values = ", ".join(f"({p}, CAST({p} AS TIMESTAMP))" for _ in keys)
    params = [v for sid, bucket in keys for v in (sid, d.time_value(bucket))]
    known = f"(VALUES {values}) AS k(k_sid, k_bucket)"
    matches = "EXISTS (SELECT 1 FROM {known} WHERE k_sid = {a}.sid AND k_bucket = {a}.bucket)"
    sids = sorted({sid for sid, _ in keys})
    where, wparams = d.sid_filter(sids)
    lo, hi = keys[0][1], keys[0][1]
    for _, bucket in keys:
        lo, hi = min(lo, bucket), max(hi, bucket)
    raw = f"(SELECT sid, rid, t, kind, num FROM {d.samples('sid, rid, t, kind, num')} WHERE {where} "
    raw += f"AND t >= {p} AND t < {p}) AS raw"
    raw_sql = samples_partials(d, level, raw, "", "WHERE " + matches.format(known=known, a="s"))
    raw_rows = fetch(raw_sql, [*wparams, d.time_value(lo), d.time_value(hi + level.width), *params])
    rolled = f"(SELECT {COLS} FROM {level.view} r WHERE {matches.format(known=known, a='r')})"
    rolled_rows = fetch(combine_partials(d, rolled), params)
    return _differences(level, {_key(r): r for r in raw_rows}, {_key(r): r for r in rolled_rows})


def _key(row: tuple) -> tuple[int, datetime]:
    return row[0], _as_utc(row[1])


def _differences(level: Level, raw: dict, rolled: dict) -> list[Difference]:
    out = []
    for key in sorted(set(raw) | set(rolled)):
        a, b = rolled.get(key), raw.get(key)
        if a is None or b is None:
            out.append(
                Difference(level.name, key[0], key[1], "row", "present" if a else None, "present" if b else None)
            )
            continue
        for column, mine, theirs in zip(COLUMNS[2:], a[2:], b[2:], strict=True):
            if not _same(column, mine, theirs):
                out.append(Difference(level.name, key[0], key[1], column, mine, theirs))
    return out


def _same(column: str, mine: object, theirs: object) -> bool:
    if column == "num_sum" and isinstance(mine, float) and isinstance(theirs, float):
        return math.isclose(mine, theirs, rel_tol=_SUM_TOLERANCE, abs_tol=_SUM_TOLERANCE)
    return mine == theirs or (isinstance(mine, (int, float)) and isinstance(theirs, (int, float)) and mine == theirs)


PAGE_ROWS = 2_000  # rollup rows a page: 16 parameters each, under PostgreSQL's 65,535


@dataclass(frozen=True, slots=True)
class ExpiredPage:
    """Rows (``COLUMNS``, one per bucket) of ``level`` of series ``sid`` that
    hold samples retention deleted, by bucket; ``upto``: the series' mark."""

    sid: int
    upto: datetime  # naive UTC, as stored
    level: Level
    rows: list[tuple]


def expired_history(store, page_rows: int = PAGE_ROWS) -> Iterator[ExpiredPage]:
    """Every series' incomplete buckets, combined per bucket, a page at a time."""
    store.sync()
    querier = store.querier()
    fetch, d = querier._fetch, querier.dialect
    p = d.placeholder
    for sid, upto in fetch(f"SELECT sid, upto FROM {EXPIRED} ORDER BY sid", []):
        for level in LEVELS:
            after = None
            while True:
                where, params = f"sid = {p} AND bucket <= {p}", [sid, upto]
                if after is not None:
                    where += f" AND bucket > {p}"
                    params.append(after)
                source = f"(SELECT {COLS} FROM {level.view} WHERE {where})"
                rows = fetch(f"{combine_partials(d, source)} ORDER BY bucket LIMIT {p}", [*params, page_rows])
                if rows:
                    yield ExpiredPage(sid, upto, level, [tuple(r) for r in rows])
                if len(rows) < page_rows:
                    break
                after = rows[-1][1]


def put_expired_history(store, page: ExpiredPage, sid: int) -> None:
    """``page`` as series ``sid``'s in ``store``: its buckets' rows replaced by
    the page's, its mark raised to the page's, in one transaction."""
    querier = store.querier()
    d = querier.dialect
    p = d.placeholder
    first, last = page.rows[0][1], page.rows[-1][1]
    span = f"sid = {p} AND bucket >= {p} AND bucket <= {p}"
    values = ", ".join(f"({', '.join([p] * len(COLUMNS))})" for _ in page.rows)
    statements: list[tuple[str, list]] = [(sql, []) for sql in lock_statements(d)]
    statements += [
        (f"DELETE FROM {page.level.table} WHERE {span}", [sid, first, last]),
        (f"DELETE FROM {HOT} WHERE level = {page.level.code} AND {span}", [sid, first, last]),
        (
            f"INSERT INTO {page.level.table} ({COLS}) VALUES {values}",
            [v for row in page.rows for v in (sid, *row[1:])],
        ),
        (
            f"INSERT INTO {EXPIRED} (sid, upto) VALUES ({p}, {p}) "
            f"ON CONFLICT (sid) DO UPDATE SET upto = greatest({EXPIRED}.upto, EXCLUDED.upto)",
            [sid, page.upto],
        ),
    ]
    store.rewrite_rollups(statements)
