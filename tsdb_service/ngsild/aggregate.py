"""The aggregated temporal representation (``format=aggregatedValues``),
computed in the database by one grouped query.

Periods (``aggrPeriodDuration``):

* start at the window's start (``timeAt`` of ``after``/``between``); for
  ``before`` or no ``timerel`` at the first instance in the window of the
  entities on the page; they follow each other without gaps;
* fixed-length durations (weeks, days, hours, minutes, seconds) are
  bucketed arithmetically; durations with years or months step through the
  calendar (adding P1M to 31 January gives the last day of February, the
  next period starts from the start plus 2 months, so there is no drift);
* ``PT0S`` (or none) is one period over the whole window, from its start
  (or the first instance) to its end (or the last instance);
* periods without instances are left out.

Methods by value type (the stored kind of each instance):

* numbers: every method; booleans count as 1 and 0;
* arrays: the methods on their sizes (``sum``, ``avg``, ``min``, ``max``, ``stddev``, ``sumsq``);
* text: ``min``/``max`` compare lexicographically;
* DateTime: ``min``, ``max`` and ``avg`` are date-times;
* Relationships, objects, languageMaps, geometries: ``totalCount`` and
  ``distinctCount`` only;
* any other combination, and one attribute mixing such families, is 400.

``stddev`` is the *population* standard deviation (divides by n), so one
instance gives 0; ``sumsq`` is the sum of squares. ``totalCount`` counts
instances with a value (deletion instances are not values), ``distinctCount``
distinct values.
"""

from __future__ import annotations

import calendar
import math
from collections.abc import Sequence
from datetime import UTC, datetime, timedelta

from ..model import Kind
from .errors import BadRequestData
from .query import Aggregation, Duration, Window

MAX_PERIODS = 100_000
_K = Kind
_NUMBERISH = {int(_K.NUMBER), int(_K.INTEGER), int(_K.BOOLEAN)}
_COUNTS = ("totalCount", "distinctCount")
_EPOCH = datetime(1970, 1, 1, tzinfo=UTC)

# Aggregate rows: (sid, bucket, kind, is_array, n, n_distinct, sum_x, sum_xx,
#                  min_x, max_x, min_txt, max_txt, all_integer, min_us, max_us)


def us_to_datetime(us: int) -> datetime:
    return _EPOCH + timedelta(microseconds=us)


def datetime_to_us(moment: datetime) -> int:
    delta = moment - _EPOCH
    return (delta.days * 86_400 + delta.seconds) * 1_000_000 + delta.microseconds


def add_months(moment: datetime, months: int) -> datetime:
    """``moment`` plus whole months, the day clamped to the month's end."""
    index = moment.year * 12 + moment.month - 1 + months
    year, month = divmod(index, 12)
    if not 1 <= year <= 9999:
        raise BadRequestData("aggregation periods run past the year 9999")
    day = min(moment.day, calendar.monthrange(year, month + 1)[1])
    return moment.replace(year=year, month=month + 1, day=day)


def boundaries(start: datetime, end: datetime, period: Duration) -> list[int]:
    """Period starts (epoch µs) from ``start`` until one reaches ``end``, plus that last one."""
    out = []
    k = 0
    while True:
        moment = add_months(start, k * period.months) + timedelta(days=k * period.days,
                                                                   microseconds=k * period.micros)
        out.append(datetime_to_us(moment))
        if moment >= end:
            return out
        k += 1
        if k > MAX_PERIODS:
            raise BadRequestData(f"aggrPeriodDuration makes more than {MAX_PERIODS} periods in this window")


class Aggregator:
    def __init__(self, fetcher):
        self.f = fetcher
        self.d = fetcher.d

    def run(self, sids: Sequence[int], window: Window, agg: Aggregation) -> dict[int, list[tuple[int, int, dict]]]:
        """sid → [(period start µs, period end µs, {method: value})], periods in order."""
        if not sids:
            return {}
        period = agg.period
        if period.zero:
            rows = self._query(sids, window, "0", [])
            return self._whole(rows, window, agg.methods)
        if not period.calendar:
            start = window.start
            if start is None:
                bounds = self._span(sids, window)
                if bounds is None:
                    return {}
                start_us = bounds[0]
            else:
                start_us = datetime_to_us(start)
            step = period.fixed_micros
            tp = self.d.epoch_us("tp")
            p = self.d.placeholder
            rows = self._query(sids, window, f"CAST(floor(({tp} - {p}) / CAST({p} AS DOUBLE PRECISION)) AS BIGINT)",
                               [start_us, step])
            return self._combine(rows, agg.methods, lambda b: (start_us + b * step, start_us + (b + 1) * step))
        bounds = self._span(sids, window)
        if bounds is None:
            return {}
        start = window.start or us_to_datetime(bounds[0])
        end = window.end or us_to_datetime(bounds[1] + 1)
        edges = boundaries(start, end, period)
        rows = self._calendar_query(sids, window, edges)
        following = dict(zip(edges, edges[1:]))
        return self._combine(rows, agg.methods, lambda lo: (lo, following[lo]))

    # -- SQL -------------------------------------------------------------------------

    def _inner(self, sids: Sequence[int], window: Window) -> tuple[str, list]:
        d = self.d
        expr, where_t, params_t = self.f.time_filter(window)
        where_s, params_s = d.sid_filter(sids)
        is_array = f"(kind = {int(_K.STRUCTURED)} AND substr(js, 1, 1) = '[')"
        x = (f"CASE WHEN kind IN ({int(_K.NUMBER)}, {int(_K.INTEGER)}, {int(_K.BOOLEAN)}, {int(_K.DATETIME)}) "
             f"THEN num WHEN {is_array} THEN CAST({self._array_length('js')} AS DOUBLE PRECISION) END")
        table = d.samples("sid, t, observed_at, created_at, modified_at, deleted_at, kind, num, txt, js")
        sql = (f"SELECT sid, {expr} AS tp, kind, txt, js, num, CASE WHEN {is_array} THEN 1 ELSE 0 END AS is_array, "
               f"{x} AS x FROM {table} WHERE {where_s} AND {where_t} AND kind <> {int(_K.NULL)}")
        return sql, [*params_s, *params_t]

    def _array_length(self, col: str) -> str:
        if self.d.name == "postgresql":
            return f"jsonb_array_length(({col})::jsonb)"
        return f"json_array_length({col})"

    def _select(self) -> str:
        us = self.d.epoch_us
        return (
            "SELECT sid, bucket, kind, is_array, count(*), "
            "count(DISTINCT coalesce(txt, js, CAST(num AS VARCHAR))), sum(x), sum(x * x), min(x), max(x), "
            f"min(txt), max(txt), bool_and(kind = {int(_K.INTEGER)} OR kind = {int(_K.BOOLEAN)}), "
            f"min({us('tp')}), max({us('tp')})"
        )

    def _query(self, sids, window, bucket_sql: str, bucket_params: list) -> list[tuple]:
        inner, params = self._inner(sids, window)
        sql = (f"{self._select()} FROM (SELECT s.*, {bucket_sql} AS bucket FROM ({inner}) s) b "
               "GROUP BY sid, bucket, kind, is_array")
        # the bucket expression comes first in the text, so its parameters do too
        return self.f.q._fetch(sql, [*bucket_params, *params])

    def _calendar_query(self, sids, window, edges: list[int]) -> list[tuple]:
        inner, params = self._inner(sids, window)
        p = self.d.placeholder
        tp = self.d.epoch_us("s.tp")
        if self.d.name == "postgresql":
            periods = f"unnest({p}::bigint[], {p}::bigint[]) AS per(lo, hi)"
        else:
            periods = f"(SELECT unnest({p}::BIGINT[]) AS lo, unnest({p}::BIGINT[]) AS hi) per"
        sql = (f"{self._select()} FROM (SELECT s.*, per.lo AS bucket FROM ({inner}) s "
               f"JOIN {periods} ON {tp} >= per.lo AND {tp} < per.hi) b GROUP BY sid, bucket, kind, is_array")
        return self.f.q._fetch(sql, [*params, edges[:-1], edges[1:]])

    def _span(self, sids, window) -> tuple[int, int] | None:
        inner, params = self._inner(sids, window)
        us = self.d.epoch_us
        rows = self.f.q._fetch(f"SELECT min({us('tp')}), max({us('tp')}) FROM ({inner}) s", params)
        if not rows or rows[0][0] is None:
            return None
        return int(rows[0][0]), int(rows[0][1])

    # -- combining ---------------------------------------------------------------------

    def _whole(self, rows, window: Window, methods) -> dict[int, list[tuple[int, int, dict]]]:
        if not rows:
            return {}
        first = min(r[13] for r in rows)
        last = max(r[14] for r in rows)
        start = datetime_to_us(window.start) if window.start is not None else first
        end = datetime_to_us(window.end) if window.end is not None else last
        return self._combine(rows, methods, lambda _b: (start, end))

    def _combine(self, rows, methods, span) -> dict[int, list[tuple[int, int, dict]]]:
        by_sid: dict[int, dict[object, list[tuple]]] = {}
        for row in rows:
            by_sid.setdefault(row[0], {}).setdefault(row[1], []).append(row)
        out: dict[int, list[tuple[int, int, dict]]] = {}
        for sid, buckets in by_sid.items():
            family = _family(sid, [r for group in buckets.values() for r in group], methods)
            periods = []
            for bucket in sorted(buckets):
                lo, hi = span(bucket)
                periods.append((lo, hi, _values(buckets[bucket], family, methods)))
            out[sid] = periods
        return out


def _family(sid: int, rows: list[tuple], methods) -> str | None:
    """The one value family of a series' instances ("number", "array",
    "text", "datetime", or "other"), checked against the methods asked."""
    value_methods = [m for m in methods if m not in _COUNTS]
    families = set()
    for row in rows:
        kind, is_array = row[2], row[3]
        if kind in _NUMBERISH:
            families.add("number")
        elif is_array:
            families.add("array")
        elif kind == int(_K.TEXT):
            families.add("text")
        elif kind == int(_K.DATETIME):
            families.add("datetime")
        else:
            families.add("other")
    if not value_methods:
        return None
    if len(families) > 1:
        raise BadRequestData(f"cannot apply {', '.join(value_methods)} to an attribute whose instances mix "
                             f"{' and '.join(sorted(families))} values")
    family = families.pop()
    allowed = {
        "number": {"sum", "avg", "min", "max", "stddev", "sumsq"},
        "array": {"sum", "avg", "min", "max", "stddev", "sumsq"},
        "text": {"min", "max"},
        "datetime": {"min", "max", "avg"},
        "other": set(),
    }[family]
    refused = [m for m in value_methods if m not in allowed]
    if refused:
        what = {"other": "relationships, objects, language maps or geometries"}.get(family, f"{family} values")
        raise BadRequestData(f"aggrMethods {', '.join(refused)} cannot be applied to {what}")
    return family


def _values(rows: list[tuple], family: str | None, methods) -> dict:
    n = sum(r[4] for r in rows)
    out: dict = {}
    for method in methods:
        if method == "totalCount":
            out[method] = n
        elif method == "distinctCount":
            out[method] = sum(r[5] for r in rows)
        else:
            out[method] = _value(rows, family, method, n)
    return out


def _value(rows: list[tuple], family: str | None, method: str, n: int):
    integral = family == "number" and all(r[12] for r in rows)
    if family == "text":
        texts = [r[10] if method == "min" else r[11] for r in rows if r[10] is not None]
        return (min(texts) if method == "min" else max(texts)) if texts else None
    xs = [r for r in rows if r[6] is not None]
    count = sum(r[4] for r in xs)
    if not xs or count == 0:
        return None
    total = sum(r[6] for r in xs)
    if method == "min":
        value = min(r[8] for r in xs)
    elif method == "max":
        value = max(r[9] for r in xs)
    elif method == "sum":
        value = total
    elif method == "sumsq":
        value = sum(r[7] for r in xs)
    elif method == "avg":
        value = total / count
        integral = False
    else:  # stddev, population
        mean = total / count
        value = math.sqrt(max(0.0, sum(r[7] for r in xs) / count - mean * mean))
        integral = False
    if family == "datetime":
        return _iso_seconds(value)
    if integral and float(value).is_integer():
        return int(value)
    return value


def _iso_seconds(seconds: float) -> str:
    moment = _EPOCH + timedelta(microseconds=round(seconds * 1_000_000))
    return iso(moment)


def iso(moment: datetime) -> str:
    """UTC ``YYYY-MM-DDTHH:MM:SS.sssZ``, microseconds when they are not whole milliseconds."""
    text = moment.strftime("%Y-%m-%dT%H:%M:%S")
    micro = moment.microsecond
    return f"{text}.{micro // 1000:03d}Z" if micro % 1000 == 0 else f"{text}.{micro:06d}Z"


def iso_us(us: int | None) -> str | None:
    return None if us is None else iso(us_to_datetime(us))
