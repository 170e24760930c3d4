"""The aggregated temporal representation (``format=aggregatedValues``),
computed in the database by grouped SQL (``Querier.instance_aggregate``,
rendered by ``storage.sql.temporal``): on DuckDB one statement per request,
which also finds the start of the periods when the window has none; on
PostgreSQL an index probe finds that start first, and many series are
grouped in parts at once. Calendar periods over a window missing an end
take a first statement that finds its span.

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
* a method that does not apply to an attribute's values (``sum`` of text,
  ``avg`` of a Relationship, or of an attribute mixing such families)
  gives ``null`` for each of its periods: every combination clause 4.5.19
  allows answers 200 (6.19, 6.20), each attribute with what applies to it
  (Stellio's answer too).

``stddev`` is the *population* standard deviation (divides by n), so one
instance gives 0; ``sumsq`` is the sum of squares. ``totalCount`` counts
instances with a value (deletion instances are not values), ``distinctCount``
distinct values.
"""

from __future__ import annotations

import calendar
import math
from collections import Counter
from collections.abc import Callable, Sequence
from datetime import UTC, datetime, timedelta
from itertools import groupby, pairwise
from operator import itemgetter, truediv
from typing import NamedTuple

from tsdb_service.core.errors import BadRequestData
from tsdb_service.core.model import Kind
from tsdb_service.core.query import InstancePeriods
from tsdb_service.core.timefmt import ld_iso as iso
from tsdb_service.core.timefmt import ld_iso_us as iso_us
from tsdb_service.faces.ngsild.fetch import Fetcher, instance_window
from tsdb_service.faces.ngsild.query import Aggregation, Duration, Window
from tsdb_service.read.requests import InstanceAggregateRead, InstancesIn

MAX_PERIODS = 100_000
_K = Kind
_NUMBERISH = {int(_K.NUMBER), int(_K.INTEGER), int(_K.BOOLEAN)}
_COUNTS = ("totalCount", "distinctCount")
_EPOCH = datetime(1970, 1, 1, tzinfo=UTC)

_INTEGRAL = {int(_K.INTEGER), int(_K.BOOLEAN)}
LD_TYPES = frozenset(
    {
        "Property",
        "GeoProperty",
        "Relationship",
        "LanguageProperty",
        "ListProperty",
        "ListRelationship",
        "VocabProperty",
        "JsonProperty",
    }
)

# Aggregate rows (``query.InstanceAggregateRow``): one per (series, period,
# kind, is-array, notified type).
(
    R_SID,
    R_BUCKET,
    R_KIND,
    R_IS_ARRAY,
    R_ATYPE,
    R_N,
    R_DISTINCT,
    R_NX,
    R_SX,
    R_SXX,
    R_MIN,
    R_MAX,
    R_MIN_TXT,
    R_MAX_TXT,
    R_MIN_US,
    R_MAX_US,
) = range(16)
_SID, _BUCKET, _MAX_US = itemgetter(R_SID), itemgetter(R_BUCKET), itemgetter(R_MAX_US)
_SHAPE = itemgetter(R_KIND, R_IS_ARRAY, R_ATYPE)
_NX, _SX = itemgetter(R_NX), itemgetter(R_SX)


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
        moment = add_months(start, k * period.months) + timedelta(days=k * period.days, microseconds=k * period.micros)
        out.append(datetime_to_us(moment))
        if moment >= end:
            return out
        k += 1
        if k > MAX_PERIODS:
            raise BadRequestData(f"aggrPeriodDuration makes more than {MAX_PERIODS} periods in this window")


class Aggregator:
    """One grouped SQL statement per request (``Querier.instance_aggregate``):
    the database filters, buckets and aggregates; Python lays out the
    periods, merges the few (kind, type) groups of a period and applies the
    spec's type rules."""

    def __init__(self, fetcher: Fetcher):
        self.q = fetcher.q

    def run(self, sids: Sequence[int], window: Window, agg: Aggregation) -> dict[int, SeriesAggregate]:
        """sid → its NGSI-LD attribute type and periods, in order, bounds
        already as text (every series of a response shares them)."""
        if not sids:
            return {}
        period, methods = agg.period, agg.methods
        where = instance_window(window)
        if period.zero:
            rows = self.q.instance_aggregate(InstanceAggregateRead(sids, where, methods, InstancePeriods()))
            return self._whole(rows, window, methods)
        if not period.calendar:
            step = period.fixed_micros
            origin = datetime_to_us(window.start) if window.start is not None else None
            rows = self.q.instance_aggregate(InstanceAggregateRead(sids, where, methods, InstancePeriods(step, origin)))
            return self._combine(rows, methods, lambda lo: (lo, lo + step))
        start, end = window.start, window.end
        if start is None or end is None:  # calendar periods need both ends to lay out the months
            bounds = self.q.instance_span(InstancesIn(sids, where))
            if bounds is None:
                return {}
            start = start or us_to_datetime(bounds[0])
            end = end or us_to_datetime(bounds[1] + 1)
        edges = boundaries(start, end, period)
        periods = InstancePeriods(edges=tuple(edges))
        rows = self.q.instance_aggregate(InstanceAggregateRead(sids, where, methods, periods))
        following = dict(pairwise(edges))
        return self._combine(rows, methods, lambda lo: (lo, following[lo]))

    # -- combining ---------------------------------------------------------------------

    def _whole(self, rows, window: Window, methods) -> dict[int, SeriesAggregate]:
        if not rows:
            return {}
        start = datetime_to_us(window.start) if window.start is not None else min(r[R_MIN_US] for r in rows)
        end = datetime_to_us(window.end) if window.end is not None else max(r[R_MAX_US] for r in rows)
        return self._combine(rows, methods, lambda _b: (start, end))

    def _combine(self, rows, methods, span: Callable[[int], tuple[int, int]]) -> dict[int, SeriesAggregate]:
        rows.sort(key=_BUCKET)  # two stable sorts on one int each: no key tuple per row
        rows.sort(key=_SID)
        bounds: dict[int, tuple[str, str]] = {}  # the series of a response share their periods: format each once
        for bucket in set(map(_BUCKET, rows)):
            lo, hi = span(bucket)
            bounds[bucket] = (iso_us(lo), iso_us(hi))
        methods = tuple(methods)
        if len(set(map(_SHAPE, rows))) == 1:  # one value shape, so one row per period: nearly always
            return self._uniform(rows, methods, bounds)
        out: dict[int, SeriesAggregate] = {}
        for sid, group in groupby(rows, key=_SID):
            series = list(group)
            family = _family(series, methods)
            newest = max(series, key=_MAX_US)
            periods = [(bucket, _one(list(parts))) for bucket, parts in groupby(series, key=_BUCKET)]
            pickers = [_picker(method, family) for method in methods]
            out[sid] = SeriesAggregate(
                type_name(newest[R_ATYPE], newest[R_KIND]),
                [[(pick(row), *bounds[bucket]) for bucket, row in periods] for pick in pickers],
            )
        return out

    @staticmethod
    def _uniform(rows, methods: tuple[str, ...], bounds) -> dict[int, SeriesAggregate]:
        """Every row of the same kind, array-ness and notified type (the
        rows' grouping keys besides series and period), so one per period:
        the family is checked once, each method's values are one column
        over all rows (``_column``), and each series takes its slice."""
        family = _family(rows[:1], methods)
        kind = rows[0][R_KIND]
        attr_type = type_name(rows[0][R_ATYPE], kind)
        buckets = list(map(_BUCKET, rows))
        los = list(map({b: lo for b, (lo, _) in bounds.items()}.__getitem__, buckets))
        his = list(map({b: hi for b, (_, hi) in bounds.items()}.__getitem__, buckets))
        periods = [list(zip(_column(method, family, kind, rows), los, his, strict=True)) for method in methods]
        out: dict[int, SeriesAggregate] = {}
        start = 0
        for sid, count in Counter(map(_SID, rows)).items():  # rows are sorted by series
            end = start + count
            out[sid] = SeriesAggregate(attr_type, [method_periods[start:end] for method_periods in periods])
            start = end
        return out


def _column(method: str, family: str | None, kind: int, rows: list[tuple]) -> list:
    """One method's value of every row (all of one kind): ``_picker``'s,
    computed by C-level maps where every row has numbers (a response holds
    thousands of periods)."""
    numbers = family in ("number", "array") and all(map(_NX, rows))
    if numbers and method == "avg":
        return list(map(truediv, map(_SX, rows), map(_NX, rows)))
    if numbers and method in ("min", "max") and not (family == "number" and kind in _INTEGRAL):
        return list(map(itemgetter(R_MIN if method == "min" else R_MAX), rows))
    return list(map(_picker(method, family), rows))


class SeriesAggregate(NamedTuple):
    attr_type: str  # the NGSI-LD type of the newest instance
    # per method asked, in order: its (value, period start, period end) per period, in time order
    values: list[list[tuple[object, str, str]]]


def type_name(atype: str | None, kind: int) -> str:
    """The NGSI-LD attribute type an instance renders as: the notified one,
    else from what the value is (NGSIv2 samples)."""
    if atype in LD_TYPES:
        return atype
    if kind == int(_K.RELATIONSHIP):
        return "Relationship"
    if kind == int(_K.GEO):
        return "GeoProperty"
    return "Property"


_APPLIES = {
    "number": frozenset({"sum", "avg", "min", "max", "stddev", "sumsq"}),
    "array": frozenset({"sum", "avg", "min", "max", "stddev", "sumsq"}),
    "text": frozenset({"min", "max"}),
    "datetime": frozenset({"min", "max", "avg"}),
}


def _family(rows: list[tuple], methods) -> str | None:
    """The one value family of a series' instances ("number", "array",
    "text", "datetime", "other", or "mixed"); None when only counts are asked."""
    value_methods = [m for m in methods if m not in _COUNTS]
    if not value_methods:
        return None
    families = set()
    for row in rows:
        kind = row[R_KIND]
        if kind in _NUMBERISH:
            families.add("number")
        elif row[R_IS_ARRAY]:
            families.add("array")
        elif kind == int(_K.TEXT):
            families.add("text")
        elif kind == int(_K.DATETIME):
            families.add("datetime")
        else:
            families.add("other")
    return families.pop() if len(families) == 1 else "mixed"


def _one(rows: list[tuple]) -> tuple:
    """A period's row: its only group, or its groups merged."""
    return rows[0] if len(rows) == 1 else _merged(rows)


def _merged(rows: list[tuple]) -> tuple:
    """A period's groups (several kinds or notified types) as one row of the
    same layout, so that one set of pickers computes every period; its kind
    says only whether all the values were integral."""
    xs = [r for r in rows if r[R_NX]]
    row = list(rows[0])
    row[R_KIND] = int(_K.INTEGER) if all(r[R_KIND] in _INTEGRAL for r in rows) else int(_K.NUMBER)
    row[R_N] = sum(r[R_N] or 0 for r in rows)
    row[R_DISTINCT] = sum(r[R_DISTINCT] or 0 for r in rows)
    row[R_NX] = sum(r[R_NX] for r in xs)
    row[R_SX] = sum(r[R_SX] or 0 for r in xs)
    row[R_SXX] = sum(r[R_SXX] or 0 for r in xs)
    row[R_MIN] = min((r[R_MIN] for r in xs if r[R_MIN] is not None), default=None)
    row[R_MAX] = max((r[R_MAX] for r in xs if r[R_MAX] is not None), default=None)
    row[R_MIN_TXT] = min((r[R_MIN_TXT] for r in rows if r[R_MIN_TXT] is not None), default=None)
    row[R_MAX_TXT] = max((r[R_MAX_TXT] for r in rows if r[R_MAX_TXT] is not None), default=None)
    return tuple(row)


def _picker(method: str, family: str | None) -> Callable[[tuple], object]:
    """One method's value of a period's row (None where the method does
    not apply to the family)."""
    if method == "totalCount":
        return itemgetter(R_N)
    if method == "distinctCount":
        return itemgetter(R_DISTINCT)
    if method not in _APPLIES.get(family or "", ()):
        return _nothing
    if family == "text":
        return itemgetter(R_MIN_TXT if method == "min" else R_MAX_TXT)
    if method == "avg" and family != "datetime":
        return lambda row: row[R_SX] / row[R_NX] if row[R_NX] else None
    if method in ("min", "max") and family != "datetime":
        at = R_MIN if method == "min" else R_MAX
        number = family == "number"

        def extreme(row: tuple) -> object:
            value = row[at]
            if not row[R_NX]:
                return None
            if number and row[R_KIND] in _INTEGRAL and float(value).is_integer():
                return int(value)
            return value

        return extreme

    def general(row: tuple) -> object:
        if not row[R_NX]:
            return None
        integral = family == "number" and row[R_KIND] in _INTEGRAL
        return _value(method, family, integral, row[R_NX], row[R_SX], row[R_SXX], row[R_MIN], row[R_MAX])

    return general


def _nothing(_row: tuple) -> None:
    return None


def _value(method: str, family: str | None, integral: bool, nx: int, sx, sxx, mn, mx):
    if method == "min":
        value = mn
    elif method == "max":
        value = mx
    elif method == "sum":
        value = sx
    elif method == "sumsq":
        value = sxx
    elif method == "avg":
        value, integral = sx / nx, False
    else:  # stddev, population
        mean = sx / nx
        value, integral = math.sqrt(max(0.0, sxx / nx - mean * mean)), False
    if family == "datetime":
        return _iso_seconds(value)
    if integral and float(value).is_integer():
        return int(value)
    return value


def _iso_seconds(seconds: float) -> str:
    moment = _EPOCH + timedelta(microseconds=round(seconds * 1_000_000))
    return iso(moment)
