"""Rollups: every series' minute and hour aggregates, exact, kept on ingest.

What long windows read instead of raw samples (the QuantumLeap aggregations
in ``storage.sql.aggregate``, the bucket query that draws), and what remains
of a series once retention deleted its raw samples (``storage.retention``).

A rollup row (``COLUMNS``) is the partial aggregate of one series' samples
in one bucket of its level (a UTC minute, a UTC hour):

* ``n_present`` samples holding a value (any kind: QuantumLeap's ``count``),
  ``n_numeric`` the numeric ones (Kind NUMBER and INTEGER with a number),
  ``n_integer`` the integers among them, ``num_sum`` their sum;
* ``num_min``/``min_us`` (the smallest number and the earliest sample time
  holding it, epoch µs), ``num_max``/``max_us`` (idem), and the first and
  last number by (time, row id) with their time and row id: what
  ``read.buckets.BucketRow`` draws.

Partials combine associatively (counts and sums add, the others pick by
their key), so a bucket may be held by several rows and every reader
combines them (``combine_partials``). Tables (migration 0014):
``rollups_minute`` and ``rollups_hour`` (merged rows) and ``rollups_hot``
(rows of both levels, ``level`` 1 or 2, appended by the writers); the views
``rollups_minute_all`` and ``rollups_hour_all`` are what readers read.
``rollups_expired`` holds, per series, the newest sample time retention
deleted (``upto``).

Invariants:

* **Never behind.** Every statement inserting samples appends their
  partials in its own transaction: on DuckDB the writer folds each batch
  (``batch_partials``: ``fold_sql`` vectorised) in the transaction that
  also moves the ingest-log position, so a replayed batch is folded
  exactly once; on
  PostgreSQL the trigger ``rollups_fold`` (migration 0014, the same SQL)
  folds each statement's new rows, whoever inserts them. ``copy`` and
  ``import quantumleap`` write through the writers.
* **Exact.** A bucket's rows combine to the partial of its raw samples plus
  those retention deleted (which is the point of keeping them). A bucket is
  *complete* while retention has deleted none of its samples: its start is
  after the series' ``rollups_expired.upto``. Deletes and NGSI-LD instance
  edits recompute the buckets they touch from raw in their own transaction
  (``recompute_statements``): every complete one, and one wholly inside a
  deleted range from what is left in it. An incomplete bucket only partly
  covered by a delete, or holding an edited instance, stays as it was: a
  minimum cannot be subtracted, and expired samples cannot be read again.
* **Merged off the write path.** ``merge`` moves hot rows into
  the level tables, combined with the rows of the same buckets, in one
  transaction. Merges, recomputes and rollup retention exclude each other
  (DuckDB: the compactor's lock; PostgreSQL: the transaction advisory lock
  ``LOCK``); appends never wait for them.
* **One snapshot per recompute on PostgreSQL**: a recompute deletes the
  hot rows of its buckets and reads their raw samples in one statement, so
  a replica committing samples of the same bucket meanwhile is counted
  once: its raw rows and its hot row are both seen, or neither.
"""

from __future__ import annotations

import logging
import threading
import time as _time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta

import numpy as np
import pyarrow as pa

from tsdb_service.core.buckets import bucket_start
from tsdb_service.core.model import Kind
from tsdb_service.core.query import TimeRange
from tsdb_service.storage.sql.dialect import SqlDialect, series_time_filter

COLUMNS = (
    "sid",
    "bucket",
    "n_present",
    "n_numeric",
    "n_integer",
    "num_sum",
    "num_min",
    "min_us",
    "num_max",
    "max_us",
    "num_first",
    "first_us",
    "first_rid",
    "num_last",
    "last_us",
    "last_rid",
)
COLS = ", ".join(COLUMNS)
log = logging.getLogger(__name__)
HOT = "rollups_hot"
EXPIRED = "rollups_expired"
LOCK = 0x7473_726F  # "tsro": PostgreSQL's merges, recomputes and rollup retention, one at a time
PRESENCE_TTL_S = 10.0
_US = timedelta(microseconds=1)
_EPOCH = datetime(1970, 1, 1, tzinfo=UTC)


@dataclass(frozen=True, slots=True)
class Level:
    """A rollup level: its code in ``rollups_hot``, its name (a
    ``date_trunc`` unit and the retention level's name) and bucket width."""

    code: int
    name: str
    width: timedelta

    @property
    def table(self) -> str:
        return f"rollups_{self.name}"

    @property
    def view(self) -> str:
        """Merged and hot rows together (what readers read)."""
        return f"rollups_{self.name}_all"


MINUTE = Level(1, "minute", timedelta(minutes=1))
HOUR = Level(2, "hour", timedelta(hours=1))
LEVELS = (MINUTE, HOUR)
LEVEL_NAMED = {level.name: level for level in LEVELS}
LEVEL_CODED = {level.code: level for level in LEVELS}


# --- the partial aggregates, per dialect -----------------------------------------------------
# Among equal values the earliest sample wins (``read.buckets``); each pick
# compares a key unique per row. DuckDB: ``arg_min``/``arg_max`` over
# HUGEINT keys (a value's ordered bits above its time, or a time above its
# row id). PostgreSQL: float8 arrays compared element by element (times in
# epoch µs and row ids are exact below 2**53).

_HIGH = f"{2**64}::HUGEINT"
_LOW = 2**62  # epoch µs + this stays in [0, 2**63)


def _duck_bits(v: str) -> str:
    bits = f"(((({v}) + 0.0)::BIT)::BIGINT)"
    return f"xor({bits}, ({bits} >> 63) & 9223372036854775807)"


def at_min(d: SqlDialect, v: str, t: str, only: str) -> str:
    """Aggregate over rows where ``only``: the time of the smallest ``v``,
    the earliest among equals."""
    if d.name == "duckdb":
        return f"arg_min({t}, {_duck_bits(v)} * {_HIGH} + ({t} + {_LOW})) FILTER (WHERE {only})"
    return f"((min(ARRAY[{v}, {t}::float8]) FILTER (WHERE {only}))[2])::bigint"


def at_max(d: SqlDialect, v: str, t: str, only: str) -> str:
    """Aggregate over rows where ``only``: the time of the largest ``v``,
    the earliest among equals."""
    if d.name == "duckdb":
        return f"arg_max({t}, {_duck_bits(v)} * {_HIGH} + ({_LOW - 1} - {t})) FILTER (WHERE {only})"
    return f"(-(max(ARRAY[{v}, (-{t})::float8]) FILTER (WHERE {only}))[2])::bigint"


def pick(d: SqlDialect, x: str, t: str, rid: str, only: str, *, last: bool, integer: bool = False) -> str:
    """Aggregate over rows where ``only``: ``x`` of the earliest (``last``:
    latest) row by (t, rid)."""
    if d.name == "duckdb":
        return f"arg_{'max' if last else 'min'}({x}, {t} * {_HIGH} + {rid}) FILTER (WHERE {only})"
    picked = f"({'max' if last else 'min'}(ARRAY[{t}::float8, {rid}::float8, {x}::float8]) FILTER (WHERE {only}))[3]"
    return f"({picked})::bigint" if integer else picked


def _aggregates(d: SqlDialect, *, v: str, t: str, rid: str, partial: bool) -> str:
    """The select list after ``sid, bucket``: over samples (``v`` the number,
    ``t`` its time in µs, ``rid`` its row id) or, ``partial``, over partial rows."""
    if partial:
        counts = ["sum(n_present)", "sum(n_numeric)", "sum(n_integer)"]
        total = "sum(num_sum)"
        mn, mn_t, mx, mx_t = "num_min", "min_us", "num_max", "max_us"
        first, first_t, first_rid = "num_first", "first_us", "first_rid"
        last, last_t, last_rid = "num_last", "last_us", "last_rid"
        numbers, firsts, lasts = "num_min IS NOT NULL", "num_first IS NOT NULL", "num_last IS NOT NULL"
    else:
        counts = [
            f"count(*) FILTER (WHERE kind <> {int(Kind.NULL)})",
            f"count({v})",
            f"count({v}) FILTER (WHERE kind = {int(Kind.INTEGER)})",
        ]
        total = f"sum({v})"
        mn = mx = first = last = v
        mn_t = mx_t = first_t = last_t = t
        first_rid = last_rid = rid
        numbers = firsts = lasts = f"{v} IS NOT NULL"
    exprs = [
        *(f"CAST({c} AS BIGINT)" for c in counts),
        total,
        f"min({mn})",
        at_min(d, mn, mn_t, numbers),
        f"max({mx})",
        at_max(d, mx, mx_t, numbers),
        pick(d, first, first_t, first_rid, firsts, last=False),
        f"min({first_t}) FILTER (WHERE {firsts})",
        pick(d, first_rid, first_t, first_rid, firsts, last=False, integer=True),
        pick(d, last, last_t, last_rid, lasts, last=True),
        f"max({last_t}) FILTER (WHERE {lasts})",
        pick(d, last_rid, last_t, last_rid, lasts, last=True, integer=True),
    ]
    return ", ".join(f"{expr} AS {name}" for expr, name in zip(exprs, COLUMNS[2:], strict=True))


def samples_partials(d: SqlDialect, level: Level, source: str, where: str = "", outer: str = "") -> str:
    """SELECT ``COLUMNS``: the partials of ``level`` of the sample rows of
    ``source`` (a FROM item with sid, rid, t, kind, num) matching ``where``
    (``WHERE ...`` text, or empty); ``outer`` filters the rows with their
    ``bucket`` computed (``WHERE ...`` text on alias ``s``)."""
    v = f"CASE WHEN kind IN ({int(Kind.NUMBER)}, {int(Kind.INTEGER)}) THEN num END"
    inner = (
        f"SELECT sid, rid, kind, date_trunc('{level.name}', t) AS bucket, {d.epoch_us('t')} AS tu, {v} AS v "
        f"FROM {source} {where}{d.fence}"
    )
    aggs = _aggregates(d, v="v", t="tu", rid="rid", partial=False)
    return f"SELECT sid, bucket, {aggs} FROM ({inner}) AS s {outer} GROUP BY sid, bucket"


def combine_partials(d: SqlDialect, source: str, bucket: str = "bucket") -> str:
    """SELECT ``COLUMNS``: the rows of ``source`` (partials) combined per
    series and ``bucket`` (an expression over their ``bucket``)."""
    aggs = _aggregates(d, v="", t="", rid="", partial=True)
    return f"SELECT sid, {bucket} AS bucket, {aggs} FROM {source} AS p GROUP BY sid, {bucket}"


def fold_sql(d: SqlDialect, source: str) -> str:
    """INSERT into ``rollups_hot`` the minute and hour partials of the sample
    rows of ``source`` (the batch a writer is inserting): the minute ones
    computed once, the hour ones combined from them."""
    minute = samples_partials(d, MINUTE, source)
    hour = combine_partials(d, "m", "date_trunc('hour', bucket)")
    return (
        f"INSERT INTO {HOT} (level, {COLS}) WITH m AS MATERIALIZED ({minute}) "
        f"SELECT {MINUTE.code}, {COLS} FROM m UNION ALL SELECT {HOUR.code}, {COLS} FROM ({hour}) AS h"
    )


_TIMESTAMP = pa.timestamp("us")


def batch_partials(batch: pa.Table) -> pa.Table:
    """``fold_sql`` over a writer's batch, vectorised (numpy, holding the
    interpreter lock for a few numpy calls rather than a loop per sample,
    and no statement to plan): the ``rollups_hot`` rows (level,
    ``COLUMNS``) of the samples of ``batch`` (an Arrow table with sid, rid,
    t, kind, num; t a timestamp), the same partials to the last tie: the
    smallest and largest number with the earliest time holding it, the
    first and last number by (time, row id), and among samples equal in
    all that the one earlier in the batch. Sums add in the batch's order.

    Both levels are grouped at once: every sample twice, keyed (level,
    sid, bucket); each pick is the head of its group in one stable sort."""
    n = batch.num_rows
    sid = np.tile(batch["sid"].to_numpy(), 2)
    rid = np.tile(batch["rid"].to_numpy(), 2)
    t = np.tile(batch["t"].to_numpy().view(np.int64), 2)
    kind = np.tile(batch["kind"].to_numpy(), 2)
    num = batch["num"]
    value = np.tile(num.to_numpy(), 2)  # NaN where null: only read where numeric
    numeric = (kind == int(Kind.NUMBER)) | (kind == int(Kind.INTEGER))
    if num.null_count:
        numeric &= np.tile(num.is_valid().to_numpy(), 2)
    level = np.repeat(np.array([MINUTE.code, HOUR.code], np.uint8), n)
    width = np.repeat(np.array([MINUTE.width // _US, HOUR.width // _US], np.int64), n)
    bucket = t - t % width
    order = np.lexsort((bucket, sid, level))
    head = _heads(level[order], sid[order], bucket[order])
    starts = order[head]
    groups = len(starts)
    group = np.empty(2 * n, np.intp)
    group[order] = np.cumsum(head) - 1
    present = kind != int(Kind.NULL)
    counts = [
        np.bincount(group[mask], minlength=groups) for mask in (present, numeric, numeric & (kind == int(Kind.INTEGER)))
    ]
    has = counts[1] > 0
    rows = np.flatnonzero(numeric)
    g, v, tn, rn = group[rows], value[rows], t[rows], rid[rows]
    total = np.bincount(g, weights=v, minlength=groups)[has]
    mn = rows[_picks(g, np.lexsort((tn, v, g)))]
    mx = rows[_picks(g, np.lexsort((tn, -v, g)))]
    first = rows[_picks(g, np.lexsort((rn, tn, g)))]
    last = rows[_picks(g, np.lexsort((-rn, -tn, g)))]
    absent = ~has
    partial = [
        total,
        value[mn],
        t[mn],
        value[mx],
        t[mx],
        value[first],
        t[first],
        rid[first],
        value[last],
        t[last],
        rid[last],
    ]
    arrays = [
        pa.array(level[starts]),
        pa.array(sid[starts]),
        pa.array(bucket[starts]).cast(_TIMESTAMP),
        *(pa.array(c) for c in counts),
        *(pa.array(_spread(c, has), mask=absent) for c in partial),
    ]
    return pa.Table.from_arrays(arrays, names=["level", *COLUMNS])


def _heads(*keys: np.ndarray) -> np.ndarray:
    """Where a run of equal keys starts, over sorted ``keys``."""
    head = np.zeros(len(keys[0]), bool)
    if len(head):
        head[0] = True
        for key in keys:
            head[1:] |= key[1:] != key[:-1]
    return head


def _picks(group: np.ndarray, order: np.ndarray) -> np.ndarray:
    """The first index of each group in ``order`` (groups sorted first)."""
    return order[_heads(group[order])]


def _spread(values: np.ndarray, has: np.ndarray) -> np.ndarray:
    """``values`` of the groups where ``has``, at their places among all."""
    out = np.zeros(len(has), values.dtype)
    out[has] = values
    return out


MIGRATION = 14  # migrations/0014_rollup_levels.*.sql


def fill_statements(d: SqlDialect, version: int) -> list[str]:
    """After migration ``version``, in its transaction: for 0014, the levels
    of every sample stored so far (raw rows are only ever read here)."""
    if version != MIGRATION:
        return []
    raw = d.samples("sid, rid, t, kind, num")
    return [
        f"INSERT INTO {level.table} ({COLS}) {samples_partials(d, level, raw)} ORDER BY sid, bucket" for level in LEVELS
    ]


# --- writing: recomputes, merges, retention ---------------------------------------------------


def _temp_table(d: SqlDialect, name: str, select: str) -> list[str]:
    """Statements making temporary table ``name`` from ``select`` for the
    rest of the transaction (one transaction may make it again)."""
    if d.name == "duckdb":
        return [f"CREATE OR REPLACE TEMP TABLE {name} AS {select}"]
    return [f"DROP TABLE IF EXISTS pg_temp.{name}", f"CREATE TEMP TABLE {name} ON COMMIT DROP AS {select}"]


def _row_id(d: SqlDialect) -> str:
    return "rowid" if d.name == "duckdb" else "ctid"


def lock_statements(d: SqlDialect) -> list[str]:
    """PostgreSQL: wait for the rollup lock (held to the transaction's end)."""
    return [] if d.name == "duckdb" else [f"SELECT pg_advisory_xact_lock({LOCK})"]


def within(
    d: SqlDialect, sids: Sequence[int], first: datetime | None = None, last: datetime | None = None
) -> tuple[str, list]:
    """WHERE text: the rows of ``sids`` with ``first <= bucket <= last``
    (None: open). Buckets are whole microseconds: ``bucket < x`` is
    ``last = x - 1 µs``."""
    p = d.placeholder
    where, params = d.sid_filter(sids)
    if first is not None:
        where += f" AND bucket >= {p}"
        params.append(d.time_value(first))
    if last is not None:
        where += f" AND bucket <= {p}"
        params.append(d.time_value(last))
    return where, params


def before(moment: datetime | None) -> datetime | None:
    """The last microsecond before ``moment`` (a half-open range's end)."""
    return None if moment is None else moment - _US


OPEN = TimeRange()
COMPLETE = f"NOT EXISTS (SELECT 1 FROM {EXPIRED} e WHERE e.sid = r.sid AND e.upto >= r.bucket)"


@dataclass(frozen=True, slots=True)
class Redo:
    """Which buckets of ``sids`` a recompute takes up: those of their
    rollup rows (and, ``from_raw``, of their raw samples) meeting ``time``
    (inclusive, None: open), or holding the instance ``(sid, iid)``. Of
    those, complete buckets are recomputed always; ``whole`` also recomputes
    incomplete ones wholly inside ``time`` (a delete: from what is left in
    them), ``every`` every one (a rebuild that drops what only rollups held)."""

    sids: Sequence[int]
    time: TimeRange = OPEN
    instance: tuple[int, int] | None = None
    whole: bool = False
    every: bool = False
    from_raw: bool = False


def _redo_keys(d: SqlDialect, redo: Redo) -> tuple[str, list]:
    """SELECT (level, sid, bucket) of the buckets ``redo`` recomputes."""
    p = d.placeholder
    parts, params = [], []
    start, end = redo.time.start, redo.time.end
    for level in LEVELS:
        # Buckets meeting [start, end]: from the one holding start on.
        where, wparams = within(d, redo.sids, None if start is None else start - level.width + _US, end)
        if redo.instance is not None:
            where += f" AND bucket = (SELECT date_trunc('{level.name}', t) FROM {d.samples('sid, iid, t')} "
            where += f"WHERE sid = {p} AND iid = {p})"
            wparams += list(redo.instance)
        candidates = f"SELECT sid, bucket FROM {level.view} WHERE {where}"
        if redo.from_raw:
            raw_where, raw_params = series_time_filter(d, redo.sids, redo.time)
            candidates += (
                f" UNION ALL SELECT sid, date_trunc('{level.name}', t) FROM {d.samples('sid, t')} WHERE {raw_where}"
            )
            wparams += raw_params
        wanted = COMPLETE
        if redo.every:
            wanted = "TRUE"
        elif redo.whole and (start is not None or end is not None):
            wholly = []
            if start is not None:
                wholly.append(f"r.bucket >= {p}")
                wparams.append(d.time_value(start))
            if end is not None:
                wholly.append(f"r.bucket <= {p}")
                wparams.append(d.time_value(end - level.width + _US))
            wanted = f"({COMPLETE} OR ({' AND '.join(wholly)}))"
        elif redo.whole:
            wanted = "TRUE"  # the whole history: every bucket is inside
        parts.append(f"SELECT DISTINCT {level.code} AS level, sid, bucket FROM ({candidates}) AS r WHERE {wanted}")
        params += wparams
    return " UNION ALL ".join(parts), params


def _raw_span(d: SqlDialect, redo: Redo) -> tuple[str, list]:
    """WHERE text bounding the raw samples a recompute reads."""
    where, params = d.sid_filter(redo.sids)
    p = d.placeholder
    if redo.instance is not None:
        where += " AND t >= (SELECT min(bucket) FROM rollups_redo) "
        where += "AND t < (SELECT max(bucket) FROM rollups_redo) + INTERVAL '1 hour'"
        return where, params
    if redo.time.start is not None:
        where += f" AND t >= {p}"
        params.append(d.time_value(bucket_start(redo.time.start, HOUR.width)))
    if redo.time.end is not None:
        where += f" AND t < {p}"
        params.append(d.time_value(bucket_start(redo.time.end, HOUR.width) + HOUR.width))
    return where, params


def _key_of(alias: str, level: Level) -> str:
    return (
        f"EXISTS (SELECT 1 FROM rollups_redo x WHERE x.level = {level.code} AND x.sid = {alias}.sid "
        f"AND x.bucket = {alias}.bucket)"
    )


def recompute_statements(d: SqlDialect, redo: Redo) -> tuple[list[tuple[str, list]], list[tuple[str, list]]]:
    """(before, after): run ``before`` ahead of the change to the raw samples
    (it names the buckets, from the rollups, and for an instance from its
    sample), ``after`` once it is made, in the same transaction."""
    keys, kparams = _redo_keys(d, redo)
    before: list[tuple[str, list]] = [(sql, []) for sql in lock_statements(d)]
    before += [(sql, kparams if sql.startswith("CREATE") else []) for sql in _temp_table(d, "rollups_redo", keys)]
    span, sparams = _raw_span(d, redo)
    raw = f"(SELECT sid, rid, t, kind, num FROM {d.samples('sid, rid, t, kind, num')} WHERE {span}) AS raw"
    redone = " UNION ALL ".join(
        f"SELECT {level.code} AS level, {COLS} "
        f"FROM ({samples_partials(d, level, raw, '', 'WHERE ' + _key_of('s', level))}) AS q{level.code}"
        for level in LEVELS
    )
    rparams = sparams * len(LEVELS)
    hot_gone = "EXISTS (SELECT 1 FROM rollups_redo x WHERE x.level = h.level AND x.sid = h.sid AND x.bucket = h.bucket)"
    after: list[tuple[str, list]] = []
    if d.name == "duckdb":
        after += [(sql, rparams) for sql in _temp_table(d, "rollups_redone", redone)]
        after.append((f"DELETE FROM {HOT} h WHERE {hot_gone}", []))
    else:  # the hot rows go in the statement that reads raw: one snapshot
        empty = f"SELECT level, {COLS} FROM {HOT} WITH NO DATA"
        after += [(sql, []) for sql in _temp_table(d, "rollups_redone", empty)]
        gone = f"WITH gone AS (DELETE FROM {HOT} h WHERE {hot_gone})"
        after.append((f"{gone} INSERT INTO rollups_redone (level, {COLS}) {redone}", rparams))
    for level in LEVELS:
        after.append((f"DELETE FROM {level.table} r WHERE {_key_of('r', level)}", []))
        after.append(
            (f"INSERT INTO {level.table} ({COLS}) SELECT {COLS} FROM rollups_redone WHERE level = {level.code}", [])
        )
    return before, after


Run = Callable[[str, list], list[tuple]]  # execute one statement in the caller's transaction: its rows


def merge(d: SqlDialect, run: Run, limit: int) -> int:
    """Move at most ``limit`` hot rows into the level tables, each bucket
    combined with its merged row, in the caller's transaction (which holds
    the rollup lock: ``lock_statements``, or DuckDB's compactor lock); how
    many moved. The merged rows of a level are looked for only from the
    oldest bucket moving on (recent, usually: the tables grow in time order)."""
    rid = _row_id(d)
    for sql in _temp_table(d, "rollups_moving", f"SELECT {rid} AS r, level, {COLS} FROM {HOT} LIMIT {int(limit)}"):
        run(sql, [])
    moved = 0
    for level, oldest, count in run("SELECT level, min(bucket), count(*) FROM rollups_moving GROUP BY level", []):
        moved += int(count)
        table = LEVEL_CODED[int(level)].table
        same = (
            f"b.bucket >= {d.placeholder} AND EXISTS (SELECT 1 FROM rollups_moving m WHERE m.level = {int(level)} "
            "AND m.sid = b.sid AND m.bucket = b.bucket)"
        )
        source = (
            f"(SELECT {COLS} FROM rollups_moving WHERE level = {int(level)} "
            f"UNION ALL SELECT {COLS} FROM {table} b WHERE {same})"
        )
        for sql in _temp_table(d, "rollups_merged", combine_partials(d, source)):
            run(sql, [oldest] if sql.startswith("CREATE") else [])
        run(f"DELETE FROM {table} b WHERE {same}", [oldest])
        run(f"INSERT INTO {table} ({COLS}) SELECT {COLS} FROM rollups_merged ORDER BY sid, bucket", [])
    run(f"DELETE FROM {HOT} WHERE {rid} IN (SELECT r FROM rollups_moving)", [])
    return moved


def expire_sql(source: str) -> str:
    """Record in ``rollups_expired`` the newest time of the rows of
    ``source`` (sid, t) that retention is deleting."""
    return (
        f"INSERT INTO {EXPIRED} (sid, upto) SELECT sid, max(t) FROM {source} GROUP BY sid ORDER BY sid "
        f"ON CONFLICT (sid) DO UPDATE SET upto = greatest({EXPIRED}.upto, EXCLUDED.upto)"
    )


def level_delete_sql(
    d: SqlDialect, level: Level, table: str, sids: Sequence[int], cutoff: datetime, limit: int
) -> tuple[str, list]:
    """At most ``limit`` rows of ``level`` in ``table`` (its merged table or
    ``rollups_hot``) of ``sids`` whose whole bucket is older than ``cutoff``."""
    where, params = d.sid_filter(sids)
    p, rid = d.placeholder, _row_id(d)
    if table == HOT:
        where += f" AND level = {level.code}"
    sql = f"DELETE FROM {table} WHERE {rid} IN (SELECT {rid} FROM {table} WHERE {where} AND bucket <= {p} LIMIT {p})"
    return sql, [*params, d.time_value(cutoff - level.width), limit]


class Merger:
    """A thread that merges hot rollup rows every ``interval`` seconds
    (PostgreSQL; DuckDB's compactor does it): ``merge_once(limit)`` moves at
    most ``limit`` rows and says how many; a full batch is followed at once
    by the next."""

    def __init__(self, merge_once, interval: float = 2.0, limit: int = 20_000):
        self._merge_once = merge_once
        self._interval = interval
        self._limit = limit
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, name="tsdb-rollup-merger", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        """Finish the merge in progress (one transaction), then stop."""
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join()

    def _loop(self) -> None:
        while not self._stop.wait(self._interval):
            try:
                while self._merge_once(self._limit) >= self._limit and not self._stop.is_set():
                    pass
            except Exception:  # keep serving: readers combine hot rows meanwhile
                log.exception("merging rollups failed; will retry")


class ExpiryPresence:
    """Whether retention may have deleted raw samples anywhere in the store
    (``rollups_expired`` holds rows), so that aggregations skip the hourly
    partials in memory, which know raw samples only.

    Known present: stays so. Otherwise the table is looked at no more often
    than every ``ttl`` seconds; a store whose own retention deletes says so
    at once (``mark``)."""

    def __init__(self, ttl: float = PRESENCE_TTL_S):
        self._present = False
        self._ttl = ttl
        self._checked = float("-inf")
        self._lock = threading.Lock()

    def mark(self) -> None:
        self._present = True

    def __call__(self, fetch) -> bool:
        if self._present:
            return True
        with self._lock:
            if _time.monotonic() - self._checked >= self._ttl:
                self._present = bool(fetch(f"SELECT 1 FROM {EXPIRED} LIMIT 1", []))
                self._checked = _time.monotonic()
        return self._present


def presence_of(store) -> ExpiryPresence:
    """The store's presence tracker (created on first use)."""
    presence = store.rollup_presence
    if presence is None:
        presence = store.rollup_presence = ExpiryPresence()
    return presence
