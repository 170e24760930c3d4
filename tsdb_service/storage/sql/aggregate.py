"""Aggregations over SQL: per series and period, from the hourly partials in
memory where a backend keeps them (``storage.partials``), else one statement."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from datetime import UTC, datetime, timedelta
from functools import partial

from tsdb_service.core import budget
from tsdb_service.core.query import AggBranch, AggregateRow, Aggregation, AggrMethod, AggrPeriod, RowMask, TimeRange
from tsdb_service.read.requests import AggregateRead
from tsdb_service.storage.columns import to_micros
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
from tsdb_service.storage.rollup_reads import PERIOD_LEVELS, aggregate_part, split_window
from tsdb_service.storage.sql.dialect import INTEGER_KIND, MAX_BIGINT, NULL_KIND, NUMERIC_KINDS, rows_as
from tsdb_service.storage.sql.reads import SqlReads

as_aggregate = rows_as(AggregateRow)
_new_aggregate = partial(tuple.__new__, AggregateRow)


class SqlAggregates(SqlReads):
    def aggregate(self, ask: AggregateRead) -> list[AggregateRow]:
        """See ``SampleReader``. Plain attributes from the hourly partials in memory
        where the backend keeps them and they give SQL's answer
        (``storage.partials``: hour-aligned periods, no geo mask, no raw
        sample deleted by retention); everything else in one statement
        (``_aggregate_sql``)."""
        branches, time, agg, mask = ask.branches, ask.time, ask.agg, ask.mask
        partials = self._partials() if mask is None else None
        if (
            partials is None
            or (agg.period is not None and agg.period not in PARTIAL_PERIODS)
            or not any(b.sids and not b.steps for b in branches)
            or self.raw_expired()
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
        """One statement: grouped SELECTs per branch, UNION ALL. A plain
        attribute's whole hours and minutes come from the rollups
        (``storage.rollups``: whole buckets of the period's levels, one
        snapshot with the raw edges); value paths and geo masks read raw
        samples only. Per sample it only tests ``kind`` and reads ``num`` (the
        columns PostgreSQL's covering index holds): "all integers" is counted
        (integers = numbers), not ``bool_and``-ed, and the bucket is a cheap
        key formatted once per group."""
        parts: list[str] = []
        params: list = []
        levels = PERIOD_LEVELS.get(agg.period, ()) if mask is None else ()
        for number, branch in enumerate(branches):
            if not branch.sids:
                continue
            pieces = split_window(time, levels if not branch.steps else ())
            for piece in pieces:
                if piece.level is None:
                    sql, more = self._aggregate_branch(number, branch, TimeRange(piece.start, piece.end), agg, mask)
                else:
                    sql, more = aggregate_part(self.dialect, number, branch.sids, piece, agg.method, agg.period)
                parts.append(sql)
                params += more
        if not parts:
            return []
        sql = " UNION ALL ".join(parts)
        if len(parts) > sum(1 for b in branches if b.sids):  # pieces of one bucket: one row again
            sql = _combined(sql, agg.method)
        if budget.current() is not None:  # one row past the request's budget detects an overflow
            sql = f"SELECT * FROM ({sql}) AS parts LIMIT {self.dialect.placeholder}"
            params.append(budget.row_cap(MAX_BIGINT))
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


def _combined(union: str, method: AggrMethod) -> str:
    """The rows of ``union`` (the aggregate layout) combined per series and
    bucket, as the history layer would: counts and sums add, minimum and
    maximum of the pieces, "all integers" of all of them."""
    value = {AggrMethod.MIN: "min(value)", AggrMethod.MAX: "max(value)", AggrMethod.COUNT: "NULL"}.get(
        method, "sum(value)"
    )
    return (
        "SELECT branch, sid, bucket, CAST(sum(n_present) AS BIGINT) AS n_present, "
        f"CAST(sum(n_numeric) AS BIGINT) AS n_numeric, {value} AS value, bool_and(all_integer) AS all_integer "
        f"FROM ({union}) AS pieces GROUP BY branch, sid, bucket"
    )


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
