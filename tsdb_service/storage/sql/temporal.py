"""NGSI-LD temporal reads rendered to SQL, for any backend with a ``SqlDialect``.

``ngsild`` decides what to ask (which series, which window, which test a
``q`` term makes, how aggregation periods are laid out); this module spells
it as SQL over the ``samples`` columns, and ``storage.sql.querier.SqlQuerier`` runs
it (``instances_matching``, ``instance_values``, ``location_instances``,
``instance_aggregate``, ``instance_span`` on ``base.Querier``). Values are
bound parameters; the only text put into SQL is our own.

Each function returns SQL text and its parameters; the ``*_parts`` ones a
``(head, where, params)`` triple that the querier's ``_per_series`` prefixes
with the series filter (on DuckDB one ``sid = ?`` branch per scattered
series, see ``storage.duckdb.querier``).
"""

from __future__ import annotations

from datetime import UTC, datetime
from typing import TYPE_CHECKING

from tsdb_service.core.model import Kind
from tsdb_service.core.query import (
    ANY_INSTANCE,
    ARRAY_INSTANCE,
    InstancePeriods,
    InstanceWindow,
    LocationProbe,
    Prefilter,
    ValueProbe,
    ValueTest,
)
from tsdb_service.storage.sql.dialect import box_sql

if TYPE_CHECKING:
    from collections.abc import Sequence

    from tsdb_service.storage.sql.dialect import SqlDialect

# NGSI-LD time properties → the SQL that reads them. observedAt falls back
# to the row time for samples that had none (NGSIv2 data, or NGSI-LD without
# observedAt), so every sample is an instance in observedAt order.
TIME_PROPERTY_SQL = {
    "observedAt": "coalesce(observed_at, t)",
    "createdAt": "created_at",
    "modifiedAt": "modified_at",
    "deletedAt": "deleted_at",
}
_NUMERIC = f"{int(Kind.NUMBER)}, {int(Kind.INTEGER)}"
_TEXT = f"{int(Kind.TEXT)}, {int(Kind.RELATIONSHIP)}"
_NULL = int(Kind.NULL)
_GEO = int(Kind.GEO)
_STRUCTURED = int(Kind.STRUCTURED)
_SQL_OPS = {"==": "=", ">": ">", ">=": ">=", "<": "<", "<=": "<="}
_TIME_COLUMNS = "sid, t, observed_at, created_at, modified_at, deleted_at"
_COUNTS = ("totalCount", "distinctCount")


def window_filter(d: SqlDialect, window: InstanceWindow, untimed: Sequence[int] | None = None) -> tuple[str, str, list]:
    """(time expression, WHERE fragment, params): instances whose time
    property is set and lies in the half-open ``window``.

    observedAt falls back to the row time (never NULL), and is tested as
    two ranges an index can serve, not as the ``coalesce``: on PostgreSQL
    ``(sid, observed_at)`` (migration 0008) for instances with an
    observedAt, ``(sid, t)`` for the others. A test on the coalesce reads
    every instance of the selected series. ``untimed``: the only series
    that can hold instances without observedAt, when the backend knows
    them (PostgreSQL, migration 0009); the row time is tested for those
    alone, and not at all when there are none. None: any series can.
    The window's ``spans`` narrow the series they list (``spans_filter``)."""
    expr, where, params = _window_only(d, window, untimed)
    if window.spans:
        narrowed, more = spans_filter(d, expr, window.spans)
        where, params = f"{where} AND {narrowed}", [*params, *more]
    return expr, where, params


def _window_only(d: SqlDialect, window: InstanceWindow, untimed: Sequence[int] | None) -> tuple[str, str, list]:
    expr = TIME_PROPERTY_SQL[window.timeproperty]
    if window.timeproperty != "observedAt":
        in_window, params = _in_window(d, expr, window)
        return expr, f"{expr} IS NOT NULL AND {in_window}", params
    if window.start is None and window.end is None:
        return expr, "TRUE", []
    observed, params_o = _in_window(d, "observed_at", window)
    if untimed is not None and not untimed:
        return expr, f"(observed_at IS NOT NULL AND {observed})", params_o
    row_time, params_t = _in_window(d, "t", window)
    if untimed is not None:
        listed, params_u = d.sid_filter(untimed)
        row_time, params_t = f"{listed} AND {row_time}", [*params_u, *params_t]
    where = f"((observed_at IS NOT NULL AND {observed}) OR (observed_at IS NULL AND {row_time}))"
    return expr, where, [*params_o, *params_t]


# Open ends of a span, as bound values: far outside any stored time.
_SPAN_START = datetime(1, 1, 2, tzinfo=UTC)
_SPAN_END = datetime(9999, 12, 30, tzinfo=UTC)


def spans_filter(
    d: SqlDialect, expr: str, spans: Sequence[tuple[int, datetime | None, datetime | None]]
) -> tuple[str, list]:
    """SQL: a series the spans do not list, or an instance (time property
    ``expr``) inside one of its series' spans (``InstanceWindow.spans``).
    ``sid`` is the enclosing query's column."""
    listed, params_l = d.sid_filter(sorted({sid for sid, _, _ in spans}))
    sids = [sid for sid, _, _ in spans]
    starts = [d.time_value(start or _SPAN_START) for _, start, _ in spans]
    ends = [d.time_value(end or _SPAN_END) for _, _, end in spans]
    sql = (
        f"(NOT ({listed}) OR EXISTS (SELECT 1 FROM {d.spans_relation()} "
        f"WHERE s_sid = sid AND {expr} >= s_start AND {expr} < s_end))"
    )
    return sql, [*params_l, sids, starts, ends]


def _in_window(d: SqlDialect, column: str, window: InstanceWindow) -> tuple[str, list]:
    """``column`` within the half-open window's given bounds (TRUE for none)."""
    tests, params = [], []
    if window.start is not None:
        tests.append(f"{column} >= {d.placeholder}")
        params.append(d.time_value(window.start))
    if window.end is not None:
        tests.append(f"{column} < {d.placeholder}")
        params.append(d.time_value(window.end))
    return " AND ".join(tests) or "TRUE", params


def value_test_sql(d: SqlDialect, test: ValueTest) -> tuple[str, list]:
    """SQL: one instance passes ``test`` (see ``query.ValueTest``)."""
    if test.op is None:
        return f"kind <> {_NULL}", []
    if test.op == ANY_INSTANCE:
        return "TRUE", []
    if test.op == ARRAY_INSTANCE:
        return f"kind = {_STRUCTURED} AND substr(js, 1, 1) = '['", []
    op = _SQL_OPS[test.op]
    if isinstance(test.value, str):
        return f"kind IN ({_TEXT}) AND txt {op} {d.placeholder}", [test.value]
    return f"kind IN ({_NUMERIC}) AND num {op} {d.placeholder}", [test.value]


def matching_parts(
    d: SqlDialect, window: InstanceWindow, test: ValueTest, untimed: Sequence[int] | None = None
) -> tuple[str, str, list]:
    """The series with an instance in ``window`` that passes ``test``."""
    _, where_t, params_t = window_filter(d, window, untimed)
    cond, params_c = value_test_sql(d, test)
    table = d.samples(f"{_TIME_COLUMNS}, kind, num, txt, js")
    return f"SELECT DISTINCT sid FROM {table}", f"{where_t} AND {cond}", [*params_t, *params_c]


def values_parts(d: SqlDialect, window: InstanceWindow, untimed: Sequence[int] | None = None) -> tuple[str, str, list]:
    """The distinct values (and sub-properties) of the instances in ``window``."""
    _, where_t, params_t = window_filter(d, window, untimed)
    table = d.samples(f"{_TIME_COLUMNS}, kind, num, txt, js, md")
    return f"SELECT DISTINCT sid, kind, num, txt, js, md FROM {table}", f"{where_t} AND kind <> {_NULL}", params_t


def locations_parts(
    d: SqlDialect, window: InstanceWindow, prefilter: Prefilter | None, untimed: Sequence[int] | None = None
) -> tuple[str, str, list]:
    """The distinct locations in ``window`` whose stored box passes ``prefilter``."""
    _, where_t, params_t = window_filter(d, window, untimed)
    where = f"{where_t} AND kind = {_GEO} AND geo IS NOT NULL"
    params = params_t
    if prefilter is not None:
        box, box_params = box_sql(d.placeholder, prefilter)
        where += f" AND {box}"
        params = [*params_t, *box_params]
    table = d.samples(f"{_TIME_COLUMNS}, kind, geo, min_lon, min_lat, max_lon, max_lat")
    return f"SELECT DISTINCT sid, geo FROM {table}", where, params


def scan_parts(
    d: SqlDialect,
    window: InstanceWindow,
    locations: LocationProbe | None,
    tests: Sequence[ValueProbe],
) -> tuple[str, str, list, list[int], list[int]]:
    """``locations_parts`` and ``matching_parts`` as one read: (head, where,
    params, sids, roles). The caller joins the samples to the (sid, role)
    pairs (``sid``/``role`` columns ``w_sid``/``w_role``); role 0 asks for
    locations, role ``i + 1`` for ``tests[i]``. A row is (role, sid,
    GeoJSON for role 0 else NULL), distinct."""
    _, where_t, params = window_filter(d, window)
    branches: list[str] = []
    sids: list[int] = []
    roles: list[int] = []
    if locations is not None:
        box, box_params = box_sql(d.placeholder, locations[1])
        branches.append(f"(w_role = 0 AND kind = {_GEO} AND geo IS NOT NULL AND {box})")
        params = [*params, *box_params]
        sids.extend(locations[0])
        roles.extend([0] * len(locations[0]))
    for role, (test_sids, test) in enumerate(tests, start=1):
        cond, cond_params = value_test_sql(d, test)
        branches.append(f"(w_role = {role} AND {cond})")
        params = [*params, *cond_params]
        sids.extend(test_sids)
        roles.extend([role] * len(test_sids))
    columns = f"{_TIME_COLUMNS}, kind, num, txt, js, geo, min_lon, min_lat, max_lon, max_lat"
    head = f"SELECT DISTINCT w_role, sid, CASE WHEN w_role = 0 THEN geo END FROM {d.samples(columns)}"
    return head, f"{where_t} AND ({' OR '.join(branches) or 'FALSE'})", params, sids, roles


# -- aggregation (ngsild.aggregate) ---------------------------------------------------


def _instances(
    d: SqlDialect, sids: Sequence[int], window: InstanceWindow, methods: Sequence[str], untimed: Sequence[int] | None
) -> tuple[str, list]:
    """The instances in the window: time (epoch µs), kind, type, text, the
    number a method works on (``x``), whether the value is an array and,
    for ``distinctCount``, the value as text."""
    expr, where_t, params_t = window_filter(d, window, untimed)
    where_s, params_s = d.sid_filter(sids)
    is_array = f"(kind = {int(Kind.STRUCTURED)} AND substr(js, 1, 1) = '[')"
    x = (
        f"CASE WHEN kind IN ({int(Kind.NUMBER)}, {int(Kind.INTEGER)}, {int(Kind.BOOLEAN)}, {int(Kind.DATETIME)}) "
        f"THEN num WHEN {is_array} THEN CAST({d.json_array_length('js')} AS DOUBLE PRECISION) END"
    )
    dv = ", coalesce(txt, js, CAST(num AS VARCHAR)) AS dv" if "distinctCount" in methods else ""
    table = d.samples(f"{_TIME_COLUMNS}, kind, atype, num, txt, js")
    sql = (
        f"SELECT sid, {d.epoch_us(expr)} AS tp, kind, atype, txt{dv}, "
        f"CASE WHEN {is_array} THEN 1 ELSE 0 END AS is_array, {x} AS x "
        f"FROM {table} WHERE {where_s} AND {where_t} AND kind <> {_NULL}"
    )
    return sql, [*params_s, *params_t]


def _select(methods: Sequence[str], first: bool = True) -> str:
    """Aggregate columns (``query.InstanceAggregateRow``), each only when a
    method needs it: every aggregate costs, ``count(DISTINCT)`` most (it
    cannot stream). ``first``: the first instance's time is wanted (one
    period over the whole window starts there)."""
    wanted = set(methods)

    def col(sql: str, needed) -> str:
        return sql if needed else "NULL"

    return (
        f"SELECT sid, bucket, kind, is_array, atype, {col('count(*)', 'totalCount' in wanted)}, "
        f"{col('count(DISTINCT dv)', 'distinctCount' in wanted)}, {col('count(x)', wanted - set(_COUNTS))}, "
        f"{col('sum(x)', wanted & {'sum', 'avg', 'stddev'})}, {col('sum(x * x)', wanted & {'stddev', 'sumsq'})}, "
        f"{col('min(x)', 'min' in wanted)}, {col('max(x)', 'max' in wanted)}, "
        f"{col('min(txt)', 'min' in wanted)}, {col('max(txt)', 'max' in wanted)}, {col('min(tp)', first)}, max(tp)"
    )


def aggregate_sql(
    d: SqlDialect,
    sids: Sequence[int],
    window: InstanceWindow,
    methods: Sequence[str],
    periods: InstancePeriods,
    untimed: Sequence[int] | None = None,
    first_times: bool = False,
    origin: tuple[str, list] | None = None,
) -> tuple[str, list]:
    """One grouped statement (see ``Querier.instance_aggregate``).
    ``first_times``: each row's first instance time even where the
    periods do not need it. ``origin``: for periods from the first
    instance, a query (one row, column ``origin``, epoch µs) that finds it
    without the statement keeping every instance aside to take their
    minimum (a backend's index probes)."""
    inner, params = _instances(d, sids, window, methods, untimed)
    if periods.edges:
        return _calendar_sql(d, inner, params, methods, periods.edges)
    p, div = d.placeholder, d.int_div
    ctes, source, bucket_params = f"WITH s AS ({inner}{d.fence})", "s", []
    if periods.step_us is None:
        bucket = "0"
    elif periods.origin_us is not None:
        bucket = f"{p} + {p} * ((tp - {p}) {div} {p})"
        bucket_params = [periods.origin_us, periods.step_us, periods.origin_us, periods.step_us]
    elif origin is not None:  # one value, computed once (an InitPlan), ahead of the scan
        ctes = f"WITH o AS ({origin[0]}), s AS ({inner}{d.fence})"
        params = [*origin[1], *params]
        start = "(SELECT origin FROM o)"
        bucket = f"{start} + {p} * ((tp - {start}) {div} {p})"
        bucket_params = [periods.step_us, periods.step_us]
    else:  # from the first instance in the window, found by the same statement
        ctes += ", o AS (SELECT min(tp) AS origin FROM s)"
        source = "s, o"
        bucket = f"o.origin + {p} * ((tp - o.origin) {div} {p})"
        bucket_params = [periods.step_us, periods.step_us]
    first = periods.step_us is None or first_times
    sql = (
        f"{ctes} {_select(methods, first)} FROM (SELECT s.*, {bucket} AS bucket FROM {source}) b "
        "GROUP BY sid, bucket, kind, is_array, atype"
    )
    return sql, [*params, *bucket_params]


def _calendar_sql(
    d: SqlDialect, inner: str, params: list, methods: Sequence[str], edges: Sequence[int]
) -> tuple[str, list]:
    sql = (
        f"{_select(methods, first=False)} FROM (SELECT s.*, per.lo AS bucket FROM ({inner}{d.fence}) s "
        f"JOIN {d.periods_relation()} ON s.tp >= per.lo AND s.tp < per.hi) b "
        "GROUP BY sid, bucket, kind, is_array, atype"
    )
    return sql, [*params, list(edges[:-1]), list(edges[1:])]


def span_sql(
    d: SqlDialect, sids: Sequence[int], window: InstanceWindow, untimed: Sequence[int] | None = None
) -> tuple[str, list]:
    """The first and last instance times in the window (epoch µs)."""
    inner, params = _instances(d, sids, window, (), untimed)
    return f"SELECT min(tp), max(tp) FROM ({inner}) s", params
