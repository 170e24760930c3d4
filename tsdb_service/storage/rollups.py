"""Hourly rollups: what aggregation queries keep answering after retention.

Retention (``storage.retention``) deletes raw samples in batches. With
rollups on, each batch first *folds* the rows it is about to delete into
``rollups_hourly`` (migration 0004), in the same transaction: per series and
UTC hour, the partials the raw aggregation computes (``SqlQuerier.aggregate``):
samples with a value, numeric samples, their sum, min and max, and whether
they were all integers. A sample is therefore always either a raw row or
counted in a rollup row, never both and never neither, whatever order
samples arrive in (late samples included) and however batches fall.

Answering is then a plain union: ``rollup_parts`` adds a SELECT over the
rollup rows to the raw aggregation's statement (one statement, so one
snapshot sees a batch either before or after it moved rows), and the history
service combines partials of the same bucket as it already does across
series. A rollup row is used only when its whole hour lies in the query's
time range, only for plain attributes (not value paths: only the attribute's
own number is rolled up) and only for ``aggrPeriod`` hour, day, month, year
or none: minute and second buckets cannot be cut out of an hour.
"""

from __future__ import annotations

import threading
import time as _time
from collections.abc import Sequence
from datetime import timedelta

from tsdb_service.core.model import Kind
from tsdb_service.core.query import AggrMethod, AggrPeriod

TABLE = "rollups_hourly"
HOUR = timedelta(hours=1)
# Query times have millisecond precision: an hour whose last millisecond is
# in the range counts as inside it (toDate=...T12:59:59.999 covers 12:00).
ONE_MS = timedelta(milliseconds=1)
# Periods made of whole hours: their buckets are unions of rollup rows.
ROLLUP_PERIODS = frozenset({AggrPeriod.HOUR, AggrPeriod.DAY, AggrPeriod.MONTH, AggrPeriod.YEAR})
PRESENCE_TTL_S = 10.0

_NUMERIC = f"{int(Kind.NUMBER)}, {int(Kind.INTEGER)}"
_VALUE = f"CASE WHEN kind IN ({_NUMERIC}) THEN num END"


def fold_sql(source: str) -> str:
    """INSERT the hourly partials of the rows in ``source`` (columns sid, t,
    kind, num), merging into existing rows: the same definitions as the raw
    aggregation's partials, so folded and raw answers are identical."""
    return (
        f"INSERT INTO {TABLE} (sid, bucket, n_present, n_numeric, num_sum, num_min, num_max, all_integer) "
        f"SELECT sid, date_trunc('hour', t), count(*) FILTER (WHERE kind <> {int(Kind.NULL)}), "
        f"count({_VALUE}), sum({_VALUE}), min({_VALUE}), max({_VALUE}), "
        f"bool_and(kind = {int(Kind.INTEGER)}) FILTER (WHERE {_VALUE} IS NOT NULL) "
        f"FROM {source} GROUP BY sid, date_trunc('hour', t) "
        f"ON CONFLICT (sid, bucket) DO UPDATE SET "
        f"n_present = {TABLE}.n_present + EXCLUDED.n_present, "
        f"n_numeric = {TABLE}.n_numeric + EXCLUDED.n_numeric, "
        f"num_sum = coalesce({TABLE}.num_sum + EXCLUDED.num_sum, {TABLE}.num_sum, EXCLUDED.num_sum), "
        f"num_min = least({TABLE}.num_min, EXCLUDED.num_min), "
        f"num_max = greatest({TABLE}.num_max, EXCLUDED.num_max), "
        f"all_integer = coalesce({TABLE}.all_integer AND EXCLUDED.all_integer, "
        f"{TABLE}.all_integer, EXCLUDED.all_integer)"
    )


def _overlapping(dialect, sids: Sequence[int], start, end) -> tuple[str, list]:
    """WHERE text: rollup rows of ``sids`` whose hour overlaps [start, end]."""
    p = dialect.placeholder
    where, params = dialect.sid_filter(sids)
    if start is not None:
        where += f" AND bucket > {p}"
        params.append(dialect.time_value(start - HOUR))
    if end is not None:
        where += f" AND bucket <= {p}"
        params.append(dialect.time_value(end))
    return where, params


def delete_sql(dialect, sids: Sequence[int], start, end) -> tuple[str, list]:
    """DELETE the rollup rows of ``sids`` whose hour overlaps [start, end]
    (``None``: open). A user's delete must remove rolled-up history too; an
    hour the range only partly covers goes whole (a rollup row cannot be
    split), which only matters for hours retention already folded."""
    where, params = _overlapping(dialect, sids, start, end)
    return f"DELETE FROM {TABLE} WHERE {where}", params


def rolled_up_count(querier, sids: Sequence[int], time) -> int:
    """How many rolled-up hours a delete of ``sids`` in ``time`` removes, so
    that deleting history only rollups hold still finds something to delete."""
    if not querier.rollups_present():
        return 0
    where, params = _overlapping(querier.dialect, sids, time.start, time.end)
    rows = querier._fetch(f"SELECT count(*) FROM {TABLE} WHERE {where}", params)
    return int(rows[0][0]) if rows else 0


class RollupPresence:
    """Whether ``rollups_hourly`` may hold rows, so that aggregations skip
    the extra SELECT while it is certainly empty (rollups never used).

    Known present: stays so. Otherwise the table is looked at no more often
    than every ``ttl`` seconds; a store whose own worker folds rows says so
    at once (``mark``)."""

    def __init__(self, enabled: bool = False, ttl: float = PRESENCE_TTL_S):
        self._present = enabled
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
                self._present = bool(fetch(f"SELECT 1 FROM {TABLE} LIMIT 1", []))
                self._checked = _time.monotonic()
        return self._present


def presence_of(store) -> RollupPresence:
    """The store's presence tracker (created on first use)."""
    presence = store.rollup_presence
    if presence is None:
        presence = store.rollup_presence = RollupPresence()
    return presence


def rollup_parts(querier, branches, time, agg) -> tuple[str, list]:
    """A SELECT yielding the aggregate partials held in rollups, in the raw
    aggregation's row layout (branch, sid, bucket, n_present, n_numeric,
    value, all_integer), or ``("", [])`` when rollups cannot contribute."""
    if agg.period is not None and agg.period not in ROLLUP_PERIODS:
        return "", []
    plain = [(number, b) for number, b in enumerate(branches) if b.sids and not b.steps]
    if not plain or not querier.rollups_present():
        return "", []
    d = querier.dialect
    p = d.placeholder
    fn = {
        AggrMethod.SUM: "sum(num_sum)",
        AggrMethod.AVG: "sum(num_sum)",
        AggrMethod.MIN: "min(num_min)",
        AggrMethod.MAX: "max(num_max)",
    }.get(agg.method, "NULL")
    period = d.date_trunc(agg.period.value, "bucket") if agg.period is not None else None
    bucket_sql = d.iso_ms(period) if period else "NULL"
    group = "sid" + (f", {period}" if period else "")
    parts, params = [], []
    for number, branch in plain:
        where, wparams = d.sid_filter(branch.sids)
        # Whole hours only: [bucket, bucket + 1h) inside the inclusive range
        # (to the millisecond).
        if time.start is not None:
            where += f" AND bucket >= {p}"
            wparams.append(d.time_value(time.start))
        if time.end is not None:
            where += f" AND bucket <= {p}"
            wparams.append(d.time_value(time.end - HOUR + ONE_MS))
        parts.append(
            f"SELECT {number} AS branch, sid, {bucket_sql} AS bucket, "
            f"CAST(sum(n_present) AS BIGINT) AS n_present, CAST(sum(n_numeric) AS BIGINT) AS n_numeric, "
            f"{fn} AS value, bool_and(all_integer) AS all_integer "
            f"FROM {TABLE} WHERE {where} GROUP BY {group}"
        )
        params += wparams
    return " UNION ALL ".join(parts), params
