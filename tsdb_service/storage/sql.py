"""History queries rendered to SQL, for any backend with a ``Dialect``.

The renderer knows the schema (``series`` + ``samples``, see
``migrations/``) and QuantumLeap's row semantics; a ``Dialect`` knows how one
database spells placeholders, time truncation, ISO formatting, JSON paths and
regular expressions. Values are always bound parameters. The only text put
into SQL is our own: identifiers through ``quote_ident`` and aggregation
period names from the ``AggrPeriod`` enum.

``SqlQuerier`` implements the read half of the storage seam on top of one
method, ``_fetch(sql, params)``; a backend subclasses it and adds a
connection. Every query filters samples by series id first (``sid = ?`` or
``sid IN (...)``): the sample tables are sorted by (sid, t), so that filter
is what prunes them. Aggregations of plain attributes by hour-aligned
periods are answered from a backend's in-memory hourly partials where it
keeps them (``storage.partials``), loaded by one grouped statement.
"""

from __future__ import annotations

from abc import abstractmethod
from collections.abc import Callable, Collection, Iterable, Iterator, Mapping, Sequence
from datetime import UTC, datetime, timedelta
from functools import partial
from typing import Any, TypeVar

from tsdb_service.core import budget
from tsdb_service.core.model import Kind
from tsdb_service.core.query import (
    TIME_PROPERTIES,
    AggBranch,
    AggregateRow,
    Aggregation,
    AggrMethod,
    AggrPeriod,
    EntityFilter,
    ExtentRow,
    FirstLocationRow,
    GeometryRow,
    InstanceAggregateRow,
    InstancePeriods,
    InstanceRow,
    InstanceValueRow,
    InstanceWindow,
    LastValueRow,
    LatestRow,
    LocationRow,
    Prefilter,
    RawRow,
    RowMask,
    Scope,
    SeriesRef,
    StoredSample,
    TimeRange,
    ValueTest,
)
from tsdb_service.storage import temporal
from tsdb_service.storage.base import DeleteInstance, Querier, ReplaceInstance
from tsdb_service.storage.catalog import SeriesCatalog
from tsdb_service.storage.common import SAMPLE_COLUMNS, VALUE_COLUMNS, box_sql, content_values, to_micros
from tsdb_service.storage.partials import (
    ALL_INT,
    HOUR_US,
    ISO,
    MAX_LOAD_SAMPLES,
    NUMERIC,
    PRESENT,
    T_MAX,
    T_MIN,
    VALUE_SLOT,
    Accumulator,
    HourlyPartials,
    bucket_of,
)
from tsdb_service.storage.partials import PERIODS as PARTIAL_PERIODS
from tsdb_service.storage.rollups import delete_sql as rollup_delete_sql
from tsdb_service.storage.rollups import presence_of, rolled_up_count, rollup_parts

NUMERIC_KINDS = f"{int(Kind.NUMBER)}, {int(Kind.INTEGER)}"
NULL_KIND = int(Kind.NULL)
INTEGER_KIND = int(Kind.INTEGER)
GEO_KIND = int(Kind.GEO)
_MAX_BIGINT = 2**62  # LIMIT/OFFSET values stay well inside int64
_LOCATION_COLUMNS = "sid, rid, t, kind, geo, min_lon, min_lat, max_lon, max_lat"
T = TypeVar("T", bound=tuple)


def quote_ident(name: str) -> str:
    """The one way an identifier enters SQL."""
    return '"' + name.replace('"', '""') + '"'


class Dialect:
    """What differs between DuckDB and PostgreSQL. Subclass per backend."""

    name = "abstract"
    placeholder = "?"
    samples_table = "samples_all"  # every committed sample (a view on DuckDB)
    many_sids = 64  # above this many ids, bind one array instead of a list
    # Ends a subquery whose computed columns are used several times, so that
    # they are computed once a row: PostgreSQL pulls a plain subquery up
    # into its parent and then computes an expression at every use.
    fence = ""

    def samples(self, columns: str) -> str:
        """A FROM item with ``columns`` of every committed sample."""
        return self.samples_table

    def sid_filter(self, sids: Sequence[int]) -> tuple[str, list]:
        """``sid`` restricted to ``sids``: the pruning predicate."""
        p = self.placeholder
        if len(sids) == 1:
            return f"sid = {p}", [sids[0]]
        return f"sid IN ({', '.join([p] * len(sids))})", list(sids)

    def time_value(self, moment: datetime) -> object:
        """A bound value comparable with the ``t`` column."""
        return moment.astimezone(UTC).replace(tzinfo=None)

    @abstractmethod
    def iso_ms(self, expr: str) -> str:
        """``expr`` (a UTC timestamp) as ``YYYY-MM-DDTHH:MM:SS.mmm+00:00``."""

    @abstractmethod
    def epoch_us(self, expr: str) -> str:
        """``expr`` as integer microseconds since the epoch."""

    def date_trunc(self, period: str, expr: str) -> str:
        # ``period`` comes from the AggrPeriod enum, never from a request.
        return f"date_trunc('{period}', {expr})"

    def bucket_key(self, period: str, expr: str) -> str:
        """A per-row grouping key for ``period``; ``bucket_time`` turns one
        key (once per group, not per row) back into the truncated time."""
        return self.date_trunc(period, expr)

    def bucket_time(self, period: str, key: str) -> str:
        return key

    @abstractmethod
    def json_path(self, steps: tuple[str | int, ...]) -> object:
        """The bound value naming ``steps`` for the JSON functions below."""

    @abstractmethod
    def json_number(self, col: str, path: object) -> tuple[str, list]:
        """The number at ``path`` in JSON text ``col``; NULL where the path is
        missing or leads to something else than a number."""

    @abstractmethod
    def json_is_integer(self, col: str, path: object) -> tuple[str, list]:
        """True where the value at ``path`` is an integer number."""

    @abstractmethod
    def json_present(self, col: str, path: object) -> tuple[str, list]:
        """True where a non-null value exists at ``path``."""

    def mask_relation(self) -> str:
        """A FROM item of five bound arrays zipped into rows
        ``(m_sid, m_t0, m_r0, m_t1, m_r1)`` (see ``RowMask``)."""
        p = self.placeholder
        return (
            f"unnest({p}::integer[], {p}::timestamp[], {p}::bigint[], {p}::timestamp[], {p}::bigint[]) "
            "AS m(m_sid, m_t0, m_r0, m_t1, m_r1)"
        )

    # Integer division of BIGINTs (DuckDB's ``/`` divides exactly).
    int_div = "/"

    @abstractmethod
    def json_array_length(self, col: str) -> str:
        """SQL: the length of the JSON array in text column ``col``."""

    @abstractmethod
    def periods_relation(self) -> str:
        """A FROM item of two bound BIGINT arrays zipped into rows
        ``per(lo, hi)`` (consecutive periods, epoch µs)."""


def mask_filter(dialect: Dialect, mask: RowMask) -> tuple[str, list]:
    """SQL: the sample's (t, rid) lies in one of its series' mask intervals.
    ``sid``, ``t`` and ``rid`` are the enclosing query's columns."""
    return (
        f"EXISTS (SELECT 1 FROM {dialect.mask_relation()} WHERE m_sid = sid "
        "AND (t > m_t0 OR (t = m_t0 AND rid >= m_r0)) "
        "AND (m_t1 IS NULL OR t < m_t1 OR (t = m_t1 AND rid < m_r1)))",
        mask.arrays(),
    )


def box_test(dialect: Dialect, prefilter: Prefilter | None) -> tuple[str, list]:
    """SQL: a sample's stored bounding box passes ``prefilter`` (``common.box_sql``)."""
    return box_sql(dialect.placeholder, prefilter)


def rows_as(row_type: type[T]) -> Callable[[Iterable[tuple]], list[T]]:
    """Driver rows as ``row_type`` (a NamedTuple): one C-level
    ``tuple.__new__`` per row, no Python frame."""
    new = partial(tuple.__new__, row_type)
    return lambda rows: list(map(new, rows))


as_aggregate = rows_as(AggregateRow)
_new_aggregate = partial(tuple.__new__, AggregateRow)
as_latest = rows_as(LatestRow)
as_last_values = rows_as(LastValueRow)
as_geometries = rows_as(GeometryRow)
as_first_locations = rows_as(FirstLocationRow)
as_stored = rows_as(StoredSample)
_STORED_COLUMNS = ", ".join(SAMPLE_COLUMNS)


def latest_per_series(
    columns: str, source: str, where: str, *, inner: str | None = None, order: str = "t DESC, rid DESC"
) -> str:
    """SQL: ``columns`` (expressions over ``inner``, the columns read; by
    default the same) of each series' first row of ``source`` by ``order``
    (the newest by default), among those matching ``where``."""
    return (
        f"SELECT {columns} FROM (SELECT {inner or columns}, row_number() OVER (PARTITION BY sid ORDER BY {order}) "
        f"AS rn FROM {source} WHERE {where}) ranked WHERE rn = 1"
    )


# NGSI-LD time properties → the SQL that reads them (``storage.temporal``).
assert tuple(temporal.TIME_PROPERTY_SQL) == TIME_PROPERTIES
_INSTANCE_COLUMNS = "sid, iid, t, observed_at, created_at, modified_at, deleted_at, kind, atype, num, txt, js, md"
_INSTANCE_SELECT = (
    "sid, iid, {at} AS at_time, t, observed_at, created_at, modified_at, deleted_at, kind, atype, num, txt, js, md"
)
_INSTANCE_NAMES = (
    "sid, iid, at_time, t, observed_at, created_at, modified_at, deleted_at, kind, atype, num, txt, js, md"
)


def _instance_order(row: InstanceRow) -> tuple:
    return row.sid, row.at, row.iid


class SqlQuerier(Querier):
    """The read queries, rendered once for every SQL backend; the rows are
    the seam's named rows (``query``), documented on ``base.Querier``."""

    dialect: Dialect
    catalog: SeriesCatalog
    _store: Any  # the backend's store: its rollup presence tracker (``storage.rollups``)

    @abstractmethod
    def _fetch(self, sql: str, params: list) -> list[tuple]:
        """Run one read on the calling thread's connection; all its rows."""

    @abstractmethod
    def _batches(self, sql: str, params: list, size: int) -> Iterator[list[tuple]]:
        """Run one read on a cursor of its own; its rows ``size`` at a time."""

    # -- series ------------------------------------------------------------------

    def series(self, scope: Scope, entities: EntityFilter, attrs: Iterable[str] | None = None) -> list[SeriesRef]:
        return self.catalog.select(scope, entities, attrs)

    def series_names(self, scope: Scope) -> dict[str, dict[str, tuple[str, ...]]]:
        return self.catalog.names(scope.tenant)

    def tenants(self) -> list[str]:
        return self.catalog.tenants()

    def sids_with_samples(self, sids: Sequence[int]) -> set[int]:
        if not sids:
            return set()
        where, params = self.dialect.sid_filter(sids)
        sql = f"SELECT DISTINCT sid FROM {self.dialect.samples('sid')} WHERE {where}"
        return {row[0] for row in self._fetch(sql, params)}

    # -- samples -----------------------------------------------------------------

    def _where(self, sids: Sequence[int], time: TimeRange, mask: RowMask | None = None) -> tuple[str, list]:
        where, params = series_time_filter(self.dialect, sids, time)
        if mask is not None:
            test, more = mask_filter(self.dialect, mask)
            where += f" AND {test}"
            params += more
        return where, params

    def _samples(self, columns: str, mask: RowMask | None) -> str:
        """The FROM item; a mask also needs each sample's row id."""
        if mask is not None and "rid" not in columns.split(", "):
            columns += ", rid"
        return self.dialect.samples(columns)

    def raw_rows(
        self,
        sids: Sequence[int],
        time: TimeRange,
        *,
        newest_first: bool,
        limit: int,
        offset: int,
        one_per_row: bool,
        attrs_per_row: int = 1,
        mask: RowMask | None = None,
    ) -> list[RawRow]:
        """See ``Querier``. One attribute per row needs no row grouping.

        Over many series a time threshold is computed first: the M-th newest
        sample time, M = (limit + offset) x attrs_per_row, can never be newer
        than the oldest wanted row, so ``t >= threshold`` keeps every wanted
        row while the expensive ordering only sees a few candidates.
        """
        if not sids:
            return []
        d = self.dialect
        p = d.placeholder
        where, params = self._where(sids, time, mask)
        direction = "DESC" if newest_first else "ASC"
        cols = f"sid, rid, {d.iso_ms('t')}, kind, num, txt, js"
        table = d.samples("sid, rid, t, kind, num, txt, js")
        if len(sids) > 1:
            bound = "min" if newest_first else "max"
            cmp = ">=" if newest_first else "<="
            where_thr = (
                f"{where} AND t {cmp} (SELECT {bound}(t) FROM (SELECT t FROM {table} WHERE {where} "
                f"ORDER BY t {direction} LIMIT {p}) candidates)"
            )
            per_row = 1 if one_per_row else max(1, attrs_per_row)
            params_thr = [*params, *params, min((limit + offset) * per_row, _MAX_BIGINT)]
        else:
            where_thr, params_thr = where, params
        if one_per_row:
            sql = (
                f"SELECT {cols} FROM {table} WHERE {where_thr} "
                f"ORDER BY t {direction}, rid {direction} LIMIT {p} OFFSET {p}"
            )
            rows = self._fetch(sql, [*params_thr, limit, min(offset, _MAX_BIGINT)])
            if newest_first:
                rows.reverse()
            return rows
        pick = "max" if newest_first else "min"
        sql = (
            f"SELECT {cols} FROM {table} WHERE {where_thr} AND rid IN ("
            f"SELECT rid FROM {table} WHERE {where_thr} GROUP BY rid "
            f"ORDER BY {pick}(t) {direction}, rid {direction} LIMIT {p} OFFSET {p}) "
            f"ORDER BY t, rid"
        )
        return self._fetch(sql, [*params_thr, *params_thr, limit, min(offset, _MAX_BIGINT)])

    def aggregate(
        self, branches: Sequence[AggBranch], time: TimeRange, agg: Aggregation, mask: RowMask | None = None
    ) -> list[AggregateRow]:
        """See ``Querier``. Plain attributes from the hourly partials in memory
        where the backend keeps them and they give SQL's answer
        (``storage.partials``: hour-aligned periods, no geo mask, no rolled-up
        hours); everything else in one statement (``_aggregate_sql``)."""
        partials = self._partials() if mask is None else None
        if (
            partials is None
            or (agg.period is not None and agg.period not in PARTIAL_PERIODS)
            or not any(b.sids and not b.steps for b in branches)
            or self.rollups_present()
        ):
            return self._aggregate_sql(branches, time, agg, mask)
        rows: list[AggregateRow] = []
        rest = list(branches)
        for number, branch in enumerate(branches):
            if branch.sids and not branch.steps:
                rows += self._from_partials(partials, number, branch, time, agg)
                rest[number] = AggBranch(())
        if any(b.sids for b in rest):
            rows += self._aggregate_sql(rest, time, agg, None)
        return rows

    def _partials(self) -> HourlyPartials | None:
        """The backend's hourly partials, when it keeps them (it must see
        every commit, or check ``_series_versions`` before each use)."""
        return None

    def _series_versions(self, sids: Sequence[int]) -> Mapping[int, object] | None:
        """Each series' change count in the database, where writes can
        bypass this process's partials (``HourlyPartials.series``); None
        where the partials see every commit."""
        return None

    def rollups_present(self) -> bool:
        """Rolled-up hours may exist (``storage.rollups``): partials hold raw
        samples only, so aggregations then go to SQL, and a delete must look
        at the rollup rows too."""
        return presence_of(self._store)(self._fetch)

    def _from_partials(
        self, partials: HourlyPartials, number: int, branch: AggBranch, time: TimeRange, agg: Aggregation
    ) -> list[AggregateRow]:
        """One plain branch's rows from the partials; an hour cut by the window
        whose samples are not all inside it is computed from its raw rows in
        the window (one statement for all such hours)."""
        start = None if time.start is None else to_micros(time.start)
        end = None if time.end is None else to_micros(time.end)
        lo = None if start is None else start - start % HOUR_US
        entries = partials.series(branch.sids, lo, self._load_partials, self._series_versions(branch.sids))
        if entries is None:  # too many samples to load: SQL as without partials
            return self._aggregate_sql([AggBranch(()) for _ in range(number)] + [branch], time, agg)
        method, period = agg.method, agg.period
        cut: dict[tuple[int, int], list[int]] = {}  # (from, to) µs -> series to read there
        used: list[tuple[int, list[int], list[list]]] = []  # (sid, hours, cells) in the window
        for sid in branch.sids:
            hours, cells = partials.window(entries[sid], lo, end)
            i, j = 0, len(hours)
            if i < j and not _inside(hours[i], cells[i], start, end):
                cut.setdefault(_piece(hours[i], start, end), []).append(sid)
                i += 1
            if i < j and not _inside(hours[j - 1], cells[j - 1], start, end):
                cut.setdefault(_piece(hours[j - 1], start, end), []).append(sid)
                j -= 1
            if i < j:
                used.append((sid, hours[i:j], cells[i:j]))
        edges = self._cut_hours(number, cut, agg)
        if period is AggrPeriod.HOUR:
            # The common dashboard query: one ready row per cell.
            slot = VALUE_SLOT[method]
            rows = [
                _new_aggregate((number, sid, c[ISO], c[PRESENT], c[NUMERIC], c[slot], c[ALL_INT]))
                for sid, _, cells in used
                for c in cells
            ]
            rows += edges
            return rows
        acc: dict[tuple[int, str | None], Accumulator] = {}
        for sid, hours, cells in used:
            for hour, cell in zip(hours, cells, strict=True):
                key = (sid, bucket_of(period, hour)[1])
                a = acc.get(key)
                if a is None:
                    a = acc[key] = Accumulator()
                a.add_cell(cell)
        for row in edges:
            a = acc.get((row.sid, row.bucket))
            if a is None:
                a = acc[(row.sid, row.bucket)] = Accumulator()
            a.add_row(row.n_present, row.n_numeric, row.value, row.all_integer, method)
        return [
            AggregateRow(number, sid, bucket, a.present, a.numeric, a.value(method), a.all_int)
            for (sid, bucket), a in acc.items()
        ]

    def _cut_hours(self, number: int, cut: dict[tuple[int, int], list[int]], agg: Aggregation) -> list[AggregateRow]:
        """SQL's rows for the in-window parts of cut hours: one statement."""
        if not cut:
            return []
        parts, params = [], []
        for (t0, t1), sids in cut.items():
            sql, more = self._aggregate_branch(number, AggBranch(tuple(sids)), _micros_range(t0, t1), agg, None)
            parts.append(sql)
            params += more
        return as_aggregate(self._fetch(" UNION ALL ".join(parts), params))

    def _load_partials(self, sids: list[int], lo: int | None) -> list[tuple] | None:
        """``storage.partials`` load rows: per series and hour from ``lo`` on,
        the raw aggregation's partials, the numbers themselves (for an exact
        sum), the first and last sample times and the largest row id. None
        above ``MAX_LOAD_SAMPLES`` samples (counted first: a cheap scan)."""
        d = self.dialect
        where, params = d.sid_filter(sids)
        if lo is not None:
            where += f" AND t >= {d.placeholder}"
            params.append(d.time_value(_utc_micros(lo)))
        counted = self._fetch(f"SELECT count(*) FROM {d.samples('sid, t')} WHERE {where}", params)
        if counted and counted[0][0] > MAX_LOAD_SAMPLES:
            return None
        numeric = f"kind IN ({NUMERIC_KINDS}) AND num IS NOT NULL"
        sql = (
            f"SELECT sid, {d.epoch_us(d.bucket_time('hour', 'b'))}, "
            f"count(*) FILTER (WHERE kind <> {NULL_KIND}), count(num) FILTER (WHERE {numeric}), "
            f"count(num) FILTER (WHERE kind = {INTEGER_KIND}), array_agg(num) FILTER (WHERE {numeric}), "
            f"min(num) FILTER (WHERE {numeric}), max(num) FILTER (WHERE {numeric}), "
            f"{d.epoch_us('min(t)')}, {d.epoch_us('max(t)')}, max(rid) "
            f"FROM (SELECT sid, rid, t, kind, num, {d.bucket_key('hour', 't')} AS b "
            f"FROM {d.samples('sid, rid, t, kind, num')} WHERE {where}) AS s GROUP BY sid, b ORDER BY sid, b"
        )
        return self._fetch(sql, params)

    def _aggregate_sql(
        self, branches: Sequence[AggBranch], time: TimeRange, agg: Aggregation, mask: RowMask | None = None
    ) -> list[AggregateRow]:
        """One statement: a grouped SELECT per branch (and the rolled-up hours),
        UNION ALL. Per sample it only tests ``kind`` and reads ``num`` (the
        columns PostgreSQL's covering index holds): "all integers" is counted
        (integers = numbers), not ``bool_and``-ed, and the bucket is a cheap
        key formatted once per group."""
        parts: list[str] = []
        params: list = []
        for number, branch in enumerate(branches):
            if branch.sids:
                sql, more = self._aggregate_branch(number, branch, time, agg, mask)
                parts.append(sql)
                params += more
        # Retention/rollups (storage/rollups.py): hours whose raw samples
        # retention folded away, in this same statement (one snapshot).
        # Never under a geo mask: rolled-up hours carry no locations to check.
        rollup_sql, rollup_params = rollup_parts(self, branches, time, agg) if mask is None else ("", [])
        if rollup_sql:
            parts.append(rollup_sql)
            params += rollup_params
        if not parts:
            return []
        sql = " UNION ALL ".join(parts)
        if budget.current() is not None:  # one row past the request's budget detects an overflow
            sql = f"SELECT * FROM ({sql}) AS parts LIMIT {self.dialect.placeholder}"
            params.append(budget.row_cap(_MAX_BIGINT))
        return as_aggregate(self._fetch(sql, params))

    def _aggregate_branch(
        self, number: int, branch: AggBranch, time: TimeRange, agg: Aggregation, mask: RowMask | None
    ) -> tuple[str, list]:
        """One branch's grouped SELECT in the layout (branch, sid, ISO
        bucket | NULL, n_present, n_numeric, value, all_integer)."""
        d = self.dialect
        fn = {AggrMethod.SUM: "sum", AggrMethod.AVG: "sum", AggrMethod.MIN: "min", AggrMethod.MAX: "max"}.get(
            agg.method
        )
        where, wparams = self._where(branch.sids, time, mask)
        if not branch.steps:
            columns = "sid, t, kind, num"
            numeric = f"kind IN ({NUMERIC_KINDS})"
            present = f"count(*) FILTER (WHERE kind <> {NULL_KIND})"
            n_numeric = f"count(num) FILTER (WHERE {numeric})"
            value = f"{fn}(num) FILTER (WHERE {numeric})" if fn else "NULL"
            n_integer = f"count(num) FILTER (WHERE kind = {INTEGER_KIND})"
            sel_params: list = []
        else:
            columns = "sid, t, kind, num, js"
            path = d.json_path(branch.steps)
            number_sql, vparams = d.json_number("js", path)
            present_sql, pparams = d.json_present("js", path)
            is_int, iparams = d.json_is_integer("js", path)
            present = f"count(*) FILTER (WHERE {present_sql})"
            n_numeric = f"count({number_sql})"
            value = f"{fn}({number_sql})" if fn else "NULL"
            n_integer = f"count(*) FILTER (WHERE {is_int})"  # an integer is a number
            # Placeholders in textual order: present, count, value, integers.
            sel_params = [*pparams, *vparams, *(vparams if fn else []), *iparams]
        if agg.period is not None:
            period = agg.period.value
            key, group = f", {d.bucket_key(period, 't')} AS b", "sid, b"
            bucket = d.iso_ms(d.bucket_time(period, "b"))
        else:
            key, group, bucket = "", "sid", "NULL"
        inner = (
            f"SELECT sid{key}, {present} AS n_present, {n_numeric} AS n_numeric, {value} AS value, "
            f"{n_integer} AS n_integer FROM {self._samples(columns, mask)} WHERE {where} GROUP BY {group}"
        )
        sql = (
            f"SELECT {number} AS branch, sid, {bucket} AS bucket, n_present, n_numeric, value, "
            f"CASE WHEN n_numeric > 0 THEN n_integer = n_numeric END AS all_integer FROM ({inner}) AS g"
        )
        return sql, [*sel_params, *wparams]

    def latest_index(self, sids: Sequence[int], time: TimeRange, mask: RowMask | None = None) -> list[LatestRow]:
        if not sids:
            return []
        where, params = self._where(sids, time, mask)
        d = self.dialect
        sql = f"SELECT sid, {d.iso_ms('max(t)')} FROM {self._samples('sid, t', mask)} WHERE {where} GROUP BY sid"
        return as_latest(self._fetch(sql, params))

    def last_values(self, sids: Sequence[int]) -> list[LastValueRow]:
        if not sids:
            return []
        d = self.dialect
        where, params = d.sid_filter(sids)
        source = d.samples("sid, rid, t, kind, atype, num, txt, js")
        columns = "kind, atype, num, txt, js"
        sql = latest_per_series(f"sid, {d.iso_ms('t')}, {columns}", source, where, inner=f"sid, t, {columns}")
        return as_last_values(self._fetch(sql, params))

    def latest_geometries(self, sids: Sequence[int], time: TimeRange, prefilter: Prefilter | None) -> list[GeometryRow]:
        """See ``Querier``: the latest first, then the box test."""
        if not sids:
            return []
        d = self.dialect
        where, params = self._where(sids, time)
        test, test_params = box_test(d, prefilter)
        source = d.samples("sid, rid, t, kind, geo, min_lon, min_lat, max_lon, max_lat")
        latest = latest_per_series(
            "sid, geo, min_lon, min_lat, max_lon, max_lat", source, f"{where} AND kind = {GEO_KIND}"
        )
        sql = f"SELECT sid, geo FROM ({latest}) latest WHERE {test}"
        return as_geometries(self._fetch(sql, [*params, *test_params]))

    # -- locations over time (geo-queries on samples) ------------------------------

    def located_series(
        self, scope: Scope, types: Sequence[str], attrs: Iterable[str], prefilter: Prefilter | None
    ) -> list[SeriesRef]:
        """The extents (memory on DuckDB; a GiST search by box on
        PostgreSQL) give the few series near the box, each looked up in the
        catalog's (types, attrs) set, which it keeps between requests: no
        list of the types' 100,000 series per request."""
        if not scope.whole_tenant:
            return super().located_series(scope, types, attrs, prefilter)
        refs = self.catalog.by_sid(scope.tenant, types, attrs)
        return [refs[row[0]] for row in self.location_extents(refs, prefilter)]

    @abstractmethod
    def location_extents(self, sids: Collection[int], prefilter: Prefilter | None) -> list[ExtentRow]:
        """Kept by each backend (in memory on DuckDB, a table on PostgreSQL):
        from the samples it would cost a scan of every stored position."""

    def first_locations(self, sids: Sequence[int]) -> list[FirstLocationRow]:
        if not sids:
            return []
        d = self.dialect
        where, params = d.sid_filter(sids)
        located = f"{where} AND kind = {GEO_KIND} AND geo IS NOT NULL"
        source = d.samples("sid, rid, t, kind, geo")
        sql = latest_per_series(f"sid, {d.epoch_us('t')}, rid", source, located, inner="sid, t, rid", order="t, rid")
        return as_first_locations(self._fetch(sql, params))

    def location_samples(self, sids: Sequence[int], time: TimeRange, prefilter: Prefilter | None) -> list[LocationRow]:
        """See ``Querier``."""
        if not sids:
            return []
        d = self.dialect
        parts, params = self._location_rows(sids, time)
        test, test_params = box_test(d, prefilter)
        sql = (
            "SELECT sid, t_us, rid, ok, pt, min_lon, min_lat, CASE WHEN ok AND NOT pt THEN geo END FROM ("
            f"SELECT sid, {d.epoch_us('t')} AS t_us, rid, geo, min_lon, min_lat, {test} AS ok, "
            f"(min_lon = max_lon AND min_lat = max_lat) AS pt FROM ({parts}) u) x ORDER BY sid, t_us, rid"
        )
        return self._fetch(sql, [*test_params, *params])

    def _location_rows(self, sids: Sequence[int], time: TimeRange) -> tuple[str, list]:
        """SQL and parameters: the rows ``location_samples`` reads."""
        d = self.dialect
        where, params = self._where(sids, time)
        parts = (
            f"SELECT {_LOCATION_COLUMNS} FROM {d.samples(_LOCATION_COLUMNS)} "
            f"WHERE {where} AND kind = {GEO_KIND} AND geo IS NOT NULL"
        )
        if time.start is not None:
            seeds, seed_params = self._location_seeds(sids, time.start)
            parts = f"{parts} UNION ALL {seeds}"
            params += seed_params
        return parts, params

    def _location_seeds(self, sids: Sequence[int], before: datetime) -> tuple[str, list]:
        """SQL (columns as in ``location_samples``): each series' latest geo
        sample strictly before ``before``."""
        d = self.dialect
        columns = _LOCATION_COLUMNS
        where, params = d.sid_filter(sids)
        params.append(d.time_value(before))
        located = f"{where} AND t < {d.placeholder} AND kind = {GEO_KIND} AND geo IS NOT NULL"
        return latest_per_series(columns, d.samples(columns), located), params

    def count(self, sids: Sequence[int], time: TimeRange, mask: RowMask | None = None) -> int:
        """Samples of ``sids`` in ``time``; when there are none (and no geo
        mask), the rolled-up hours a delete would remove (``storage.rollups``):
        non-zero whenever a delete has something to remove."""
        if not sids:
            return 0
        where, params = self._where(sids, time, mask)
        rows = self._fetch(f"SELECT count(*) FROM {self._samples('sid, t', mask)} WHERE {where}", params)
        raw = int(rows[0][0]) if rows else 0
        if raw or mask is not None:
            return raw
        return rolled_up_count(self, sids, time)  # retention/rollups

    # -- NGSI-LD attribute instances ------------------------------------------------

    def temporal_instances(
        self,
        sids: Sequence[int],
        window: InstanceWindow | None = None,
        *,
        last_n: int | None = None,
        limit: int | None = None,
        newest_first: bool = False,
    ) -> list[InstanceRow]:
        """See ``Querier``."""
        if not sids:
            return []
        window = window or InstanceWindow()
        d = self.dialect
        p = d.placeholder
        at, in_window, window_params = temporal.window_filter(d, window, self._untimed(sids, window))
        where, params = d.sid_filter(sids)
        where += f" AND {in_window}"
        params += window_params
        table = d.samples(_INSTANCE_COLUMNS)
        cols = _INSTANCE_SELECT.format(at=at)
        direction = "DESC" if newest_first or last_n is not None else "ASC"
        if last_n is not None:
            inner = (
                f"SELECT {cols}, row_number() OVER (PARTITION BY sid ORDER BY {at} DESC, iid DESC) AS rn "
                f"FROM {table} WHERE {where}"
            )
            sql = f"SELECT {_INSTANCE_NAMES} FROM ({inner}) ranked WHERE rn <= {p}"
            params.append(min(last_n, _MAX_BIGINT))
            order = f"at_time {direction}, iid {direction}"
        else:
            sql = f"SELECT {cols} FROM {table} WHERE {where}"
            order = f"{at} {direction}, iid {direction}"
        if limit is not None:
            sql += f" ORDER BY {order} LIMIT {p}"
            params.append(min(limit, _MAX_BIGINT))
        refs = self.catalog.refs(sids)
        rows = [
            InstanceRow(
                sid,
                iid,
                at_,
                t,
                obs,
                cre,
                mod,
                dele,
                ref.dataset_id if ref is not None else None,
                kind,
                atype,
                num,
                txt,
                js,
                md,
            )
            for sid, iid, at_, t, obs, cre, mod, dele, kind, atype, num, txt, js, md in self._fetch(sql, params)
            for ref in (refs.get(sid),)
        ]
        rows.sort(key=_instance_order)
        return rows

    def instance_series(self, sids: Sequence[int], iid: int) -> int | None:
        """The one of ``sids`` that holds instance ``iid``, or None."""
        if not sids:
            return None
        d = self.dialect
        where, params = d.sid_filter(sids)
        rows = self._fetch(
            f"SELECT sid FROM {d.samples('sid, iid')} WHERE {where} AND iid = {d.placeholder}", [*params, iid]
        )
        return rows[0][0] if rows else None

    # -- NGSI-LD temporal matching and aggregation (storage.temporal) -----------------

    def instances_matching(self, sids: Sequence[int], window: InstanceWindow, test: ValueTest) -> set[int]:
        """See ``Querier``."""
        if not sids:
            return set()
        head, where, params = temporal.matching_parts(self.dialect, window, test, self._untimed(sids, window))
        return {row[0] for row in self._per_series(head, where, params, sids)}

    def instance_values(self, sids: Sequence[int], window: InstanceWindow) -> list[InstanceValueRow]:
        """See ``Querier``."""
        if not sids:
            return []
        head, where, params = temporal.values_parts(self.dialect, window, self._untimed(sids, window))
        return self._per_series(head, where, params, sids)

    def location_instances(
        self, sids: Sequence[int], window: InstanceWindow, prefilter: Prefilter | None
    ) -> list[tuple[int, str]]:
        """See ``Querier``."""
        if not sids:
            return []
        head, where, params = temporal.locations_parts(self.dialect, window, prefilter, self._untimed(sids, window))
        return self._per_series(head, where, params, sids)

    def instance_aggregate(
        self, sids: Sequence[int], window: InstanceWindow, methods: Sequence[str], periods: InstancePeriods
    ) -> list[InstanceAggregateRow]:
        """See ``Querier``."""
        if not sids:
            return []
        sql, params = temporal.aggregate_sql(self.dialect, sids, window, methods, periods, self._untimed(sids, window))
        return self._fetch(sql, params)

    def instance_span(self, sids: Sequence[int], window: InstanceWindow) -> tuple[int, int] | None:
        """See ``Querier``."""
        if not sids:
            return None
        rows = self._fetch(*temporal.span_sql(self.dialect, sids, window, self._untimed(sids, window)))
        if not rows or rows[0][0] is None:
            return None
        return int(rows[0][0]), int(rows[0][1])

    def _untimed(self, sids: Sequence[int], window: InstanceWindow) -> Sequence[int] | None:
        """Those of ``sids`` that can hold instances without observedAt, when
        the backend keeps that list and the window needs it (see
        ``temporal.window_filter``); None: any of them can."""
        return None

    def _per_series(self, head: str, where: str, params: list, sids: Sequence[int]) -> list:
        """``{head} WHERE <sid in sids> AND {where}``, all rows."""
        where_s, params_s = self.dialect.sid_filter(sids)
        return self._fetch(f"{head} WHERE {where_s} AND {where}", [*params_s, *params])

    # -- whole-store reads, for commands ---------------------------------------------

    def sample_counts(self) -> dict[str, int]:
        rows = self._fetch(
            f"SELECT s.tenant, count(*) FROM (SELECT sid FROM {self.dialect.samples('sid')}) x "
            "JOIN series s ON s.sid = x.sid "
            "GROUP BY s.tenant",
            [],
        )
        return {tenant: int(n) for tenant, n in rows}

    def stored_samples(self, batch_rows: int) -> Iterator[list[StoredSample]]:
        sql = f"SELECT {_STORED_COLUMNS} FROM {self.dialect.samples(_STORED_COLUMNS + ', iid')} ORDER BY rid, iid"
        for rows in self._batches(sql, [], batch_rows):
            yield as_stored(rows)


def _inside(hour: int, cell: list, start: int | None, end: int | None) -> bool:
    """All of an hour's samples lie in the window [start, end] (µs): the hour
    does, or its first and last samples do."""
    return (start is None or hour >= start or cell[T_MIN] >= start) and (
        end is None or hour + HOUR_US - 1 <= end or cell[T_MAX] <= end
    )


def _piece(hour: int, start: int | None, end: int | None) -> tuple[int, int]:
    """The part of ``hour`` inside the window, inclusive µs bounds."""
    last = hour + HOUR_US - 1
    return (hour if start is None else max(hour, start), last if end is None else min(last, end))


def _utc_micros(micros: int) -> datetime:
    return datetime(1970, 1, 1, tzinfo=UTC) + timedelta(microseconds=micros)


def _micros_range(t0: int, t1: int) -> TimeRange:
    return TimeRange(_utc_micros(t0), _utc_micros(t1))


def series_time_filter(dialect: Dialect, sids: Sequence[int], time: TimeRange) -> tuple[str, list]:
    """WHERE text and parameters: the series ids, then the inclusive time bounds."""
    where, params = dialect.sid_filter(sids)
    if time.start is not None:
        where += f" AND t >= {dialect.placeholder}"
        params.append(dialect.time_value(time.start))
    if time.end is not None:
        where += f" AND t <= {dialect.placeholder}"
        params.append(dialect.time_value(time.end))
    return where, params


def delete_statements(
    dialect: Dialect, tables: Sequence[str], sids: Sequence[int], time: TimeRange, upto_rid: int
) -> list[tuple[str, list]]:
    """DELETEs for the samples of ``sids`` in ``time``, written up to ``upto_rid``
    (rows appended after the delete was asked for survive it), and for their
    rolled-up hours that overlap ``time`` (``storage.rollups``)."""
    p = dialect.placeholder
    out = []
    for table in tables:
        where, params = series_time_filter(dialect, sids, time)
        where += f" AND rid <= {p}"
        params.append(upto_rid)
        out.append((f"DELETE FROM {quote_ident(table)} WHERE {where}", params))
    out.append(rollup_delete_sql(dialect, sids, time.start, time.end))  # retention/rollups
    return out


def instance_statements(
    dialect: Dialect, tables: Sequence[str], op: DeleteInstance | ReplaceInstance
) -> list[tuple[str, list]]:
    """The statements of a ``DeleteInstance`` or ``ReplaceInstance`` op
    (``storage.base``): one per sample table, each touching the one sample
    (``sid``, ``iid``). A replacement keeps the instance id, series and row
    time, and the stored observedAt when the new content has none."""
    p = dialect.placeholder
    where = f"sid = {p} AND iid = {p}"
    out = []
    for table in tables:
        if isinstance(op, DeleteInstance):
            out.append((f"DELETE FROM {quote_ident(table)} WHERE {where}", [op.sid, op.iid]))
            continue
        a = op.attr
        values = [
            *content_values(a),
            _time_or_none(dialect, a.deleted_at),
            dialect.time_value(op.modified_at),
            _time_or_none(dialect, a.observed_at),
        ]
        sets = ", ".join(f"{c} = {p}" for c in (*VALUE_COLUMNS, "deleted_at", "modified_at"))
        sets += f", observed_at = coalesce(CAST({p} AS TIMESTAMP), observed_at)"
        out.append((f"UPDATE {quote_ident(table)} SET {sets} WHERE {where}", [*values, op.sid, op.iid]))
    return out


def _time_or_none(dialect: Dialect, moment: datetime | None) -> object:
    return None if moment is None else dialect.time_value(moment)
