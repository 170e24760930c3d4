"""History reads on PostgreSQL: the shared renderer with PostgreSQL spelling.

Series ids are allocated by an identity column shared by every replica, so
they neither commit in id order nor without gaps (ON CONFLICT consumes ids).
The catalog therefore re-reads the whole ``series`` table whenever the
number of series ever inserted changes (new series are rare after
warm-up). That number is kept in ``series_generation`` (migration 0010) by
a trigger, in the inserting transaction: reading it is one row, where
counting the table took 10 ms at 200,000 series.

Reading it is still a round trip, as costly as a lastN query's own, so it
is not done per request. The catalog's change signal is (a) this process's
own writer creating series (known at once, after their commit), (b) the
counter, read at most every ``SERIES_CHECK_S`` seconds, and (c) the counter
whenever a lookup finds no series at all. So a series another replica creates is seen within
``SERIES_CHECK_S`` seconds, at once by a request that finds nothing else;
nothing else is ever stale: series are never removed, and every sample read
goes to the database.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from datetime import datetime
from operator import itemgetter
from typing import Final, Protocol

import psycopg

from tsdb_service.core import budget
from tsdb_service.core.errors import Unavailable
from tsdb_service.core.model import Kind
from tsdb_service.core.query import (
    ExtentRow,
    FirstLocationRow,
    GeometryRow,
    InstanceAggregateRow,
    InstanceWindow,
    RawRow,
    RowMask,
    SeriesRef,
    extent_prefilter,
)
from tsdb_service.read.bulk import Columns, SampleBatches
from tsdb_service.read.off_loop import check_database_allowed
from tsdb_service.read.requests import (
    ExportRead,
    ExtentsNear,
    InstanceAggregateRead,
    LocationsIn,
    RowsRead,
    SamplesIn,
    SeriesSelect,
)
from tsdb_service.storage.catalog import SeriesCatalog
from tsdb_service.storage.partials import HourlyPartials
from tsdb_service.storage.postgres.dialect import PostgresDialect, int_array
from tsdb_service.storage.sql import temporal
from tsdb_service.storage.sql.bulk import export_sql, rows_to_columns
from tsdb_service.storage.sql.dialect import MAX_BIGINT, box_test
from tsdb_service.storage.sql.locations import as_first_locations, as_geometries
from tsdb_service.storage.sql.querier import SqlQuerier


class PostgresSource(Protocol):
    """What the querier reads through (``PostgresStore`` is one)."""

    def connection(self) -> contextlib.AbstractContextManager[psycopg.Connection]:
        """A pooled connection for reads."""

    def series_created(self) -> int:
        """How many series this process's writers have created and committed."""


MANY_SIDS = 256
# A geo_extents row's box, as its GiST index (migration 0006) spells it.
_BOX = "box(point(min_lon, min_lat), point(max_lon, max_lat))"
# ``series_changes`` counts series in blocks of 2**3 ids (migration 0011).
CHANGE_BLOCK_BITS: Final = 3
# At most this stale: a series created by another replica (see above).
SERIES_CHECK_S = 1.0


_new = tuple.__new__


# From this many series an observedAt window first asks ``untimed_series``
# which of them can hold instances without observedAt (``_untimed``).
UNTIMED_LOOKUP_FROM = 16

# ``InstanceAggregateRow``: the row's period start and first instance time (epoch µs).
_BUCKET: Final = 1
_FIRST_US: Final = 14
# From this many series an aggregation is grouped in this many statements at
# once (``PostgresQuerier._fetch_parts``).
AGGREGATE_SPLIT_FROM = 32
AGGREGATE_PARTS = 2


def _one_grid(rows: list[InstanceAggregateRow], step: int) -> bool:
    """Whether every row's period lies on the grid of ``step`` from the
    first instance among ``rows``: each part's origin was the first
    instance of every series in its own snapshot, so no instance of a part
    precedes it, and a part whose origin is on that grid has the periods
    the whole answer would have."""
    if not rows:
        return True
    # C-level maps over thousands of rows; a group's first time is never
    # NULL (first_times was asked for, and every instance has a time).
    first = min(map(itemgetter(_FIRST_US), rows))
    return all((bucket - first) % step == 0 for bucket in set(map(itemgetter(_BUCKET), rows)))


def _among(listed: Sequence[int] | None, part: Sequence[int]) -> Sequence[int] | None:
    """``_untimed``'s answer for a part of the series it was asked about."""
    if listed is None:
        return None
    wanted = set(part)
    return [sid for sid in listed if sid in wanted]


class PostgresQuerier(SqlQuerier):
    def raw_rows(self, ask: RowsRead) -> list[RawRow]:
        """Under a geo mask, one attribute per row: one ``(sid, t)`` index
        scan per series in the wanted order, each stopping at its first
        ``offset + limit`` samples inside one of its mask intervals. A
        wandering entity's series has dozens of intervals (in, out, in ...):
        a scan per series tests each sample against the (materialised) mask,
        where a scan per interval would cost one index descent each."""
        sids, time, mask, newest_first, limit, offset = (
            ask.sids,
            ask.time,
            ask.mask,
            ask.newest_first,
            ask.limit,
            ask.offset,
        )
        if mask is None or not ask.one_per_row or not sids:
            return super().raw_rows(ask)
        d = self.dialect
        direction = "DESC" if newest_first else "ASC"
        window, params = "", []
        if time.start is not None:
            window += " AND x.t >= %s"
            params.append(d.time_value(time.start))
        if time.end is not None:
            window += " AND x.t <= %s"
            params.append(d.time_value(time.end))
        order = f"ORDER BY t {direction}, rid {direction}"
        wanted = min(limit + offset, MAX_BIGINT)
        subset = RowMask({sid: mask.intervals[sid] for sid in sids if sid in mask.intervals})
        sql = (
            f"WITH m AS MATERIALIZED (SELECT * FROM {d.mask_relation()}) "
            f"SELECT sid, rid, {d.iso_ms('t')}, kind, num, txt, js FROM (SELECT l.* FROM unnest(%s::integer[]) "
            "AS s(s_sid) CROSS JOIN LATERAL (SELECT x.sid, x.rid, x.t, x.kind, x.num, x.txt, x.js FROM samples x "
            "WHERE x.sid = s.s_sid AND EXISTS (SELECT 1 FROM m WHERE m.m_sid = x.sid AND x.t >= m.m_t0 "
            "AND x.t <= coalesce(m.m_t1, 'infinity'::timestamp) AND (x.t > m.m_t0 OR x.rid >= m.m_r0) "
            f"AND (m.m_t1 IS NULL OR x.t < m.m_t1 OR x.rid < m.m_r1)){window} "
            f"ORDER BY x.t {direction}, x.rid {direction} LIMIT %s) l) kept {order} LIMIT %s OFFSET %s"
        )
        series = sorted(subset.intervals)
        rows = self._fetch(sql, [*subset.arrays(), int_array(series), *params, wanted, limit, min(offset, MAX_BIGINT)])
        if newest_first:
            rows.reverse()
        return rows

    def latest_geometries(self, ask: LocationsIn) -> list[GeometryRow]:
        """One index probe per series (``(sid, t)`` index, newest first)
        instead of ranking every location sample."""
        sids, time, prefilter = ask.sids, ask.time, ask.prefilter
        if not sids:
            return []
        where, params = "", []
        if time.end is not None:
            where, params = " AND x.t <= %s", [self.dialect.time_value(time.end)]
        test, test_params = box_test(self.dialect, prefilter)
        sql = (
            "SELECT sid, geo FROM (SELECT s.sid, l.geo, l.min_lon, l.min_lat, l.max_lon, l.max_lat "
            "FROM unnest(%s::integer[]) AS s(sid) CROSS JOIN LATERAL ("
            "SELECT x.geo, x.min_lon, x.min_lat, x.max_lon, x.max_lat FROM samples x "
            f"WHERE x.sid = s.sid AND x.kind = {int(Kind.GEO)}{where} ORDER BY x.t DESC, x.rid DESC LIMIT 1) l) latest"
            f" WHERE {test}"
        )
        return as_geometries(self._fetch(sql, [int_array(sids), *params, *test_params]))

    def _untimed(self, sids: Sequence[int], window: InstanceWindow) -> Sequence[int] | None:
        """From ``untimed_series`` (migration 0009, kept by the writers, see
        ``storage.postgres.untimed``), for a window on observedAt: the row
        time is then scanned only for those series. None when all are
        listed (the usual NGSIv2 case): the plain test plans best."""
        if window.timeproperty != "observedAt" or (window.start is None and window.end is None):
            return None
        if len(sids) < UNTIMED_LOOKUP_FROM:
            return None  # a few series' second scan costs less than the look-up's round trip
        rows = self._fetch("SELECT sid FROM untimed_series WHERE sid = ANY(%s::integer[])", [int_array(sids)])
        listed = [row[0] for row in rows]
        return None if len(listed) >= len(set(sids)) else listed

    def instance_aggregate(self, ask: InstanceAggregateRead) -> list[InstanceAggregateRow]:
        """See ``TemporalReader``. The rows (one per series and period, in the
        thousands) come in binary, and from ``AGGREGATE_SPLIT_FROM`` series
        on, the series are grouped in ``AGGREGATE_PARTS`` statements at
        once (``_fetch_parts``).

        Periods that start at the first instance of an observedAt window
        find it by index probes (``_origin``), in each statement: otherwise
        the statement keeps every instance of the window aside to take
        their minimum before grouping them (3 of 11 ms over 10,000
        instances). Parts see different snapshots, so their periods must
        follow from the first instance of the whole answer
        (``_one_grid``); if a write came between them, one statement
        answers instead."""
        sids, window, methods, periods = ask.sids, ask.window, ask.methods, ask.periods
        if not sids:
            return []
        untimed = self._untimed(sids, window)
        step = periods.step_us
        if step is not None and periods.origin_us is None and (origin := self._origin(sids, window)) is not None:

            def grouped(part: Sequence[int]) -> tuple[str, list]:
                return temporal.aggregate_sql(
                    self.dialect, part, window, methods, periods, _among(untimed, part), True, origin
                )

            rows = self._fetch_parts(grouped, sids)
            if _one_grid(rows, step):
                return rows
        sql, params = temporal.aggregate_sql(self.dialect, sids, window, methods, periods, untimed)
        return self._fetch(sql, params, binary=True, prepare=False)

    def _fetch_parts(self, render: Callable[[Sequence[int]], tuple[str, list]], sids: Sequence[int]) -> list[tuple]:
        """``render(part)``'s rows (binary) for consecutive parts of
        ``sids``, run at once on as many pooled connections: one statement
        runs on one server core, and grouping 10,000 instances is CPU work
        (14 against 7 ms in two parts, on the NGSI-LD benchmark's data).
        The first part runs in this thread."""
        if len(sids) < AGGREGATE_SPLIT_FROM:
            return self._fetch(*render(sids), binary=True, prepare=False)
        size = -(-len(sids) // AGGREGATE_PARTS)
        parts = [sids[k : k + size] for k in range(0, len(sids), size)]
        others = [self._helpers.submit(self._fetch, *render(part), True, False) for part in parts[1:]]
        try:
            rows = self._fetch(*render(parts[0]), binary=True, prepare=False)
        finally:
            done = [future.result() for future in others]  # never leave a statement running unread
        for part_rows in done:
            rows.extend(part_rows)
        return rows

    def close(self) -> None:
        """Stops the helper threads (the store closes its pool)."""
        self._helpers.shutdown(wait=True)

    def _origin(self, sids: Sequence[int], window: InstanceWindow) -> tuple[str, list] | None:
        """The first instance's time (epoch µs, NULL when none) in an
        observedAt window without a start, as a query: per series the
        oldest instance with an observedAt through ``(sid, observed_at)``
        (migration 0008) and, for the series listed in ``untimed_series``
        (0009), the oldest without one through ``(sid, t)``; one index probe
        per series. None: no index serves the window's time property."""
        if window.timeproperty != "observedAt" or window.start is not None:
            return None
        end_o, end_t, end = "", "", []
        if window.end is not None:
            end_o, end_t, end = " AND x.observed_at < %s", " AND x.t < %s", [self.dialect.time_value(window.end)]
        value = f"x.kind <> {int(Kind.NULL)}"
        sql = (
            f"SELECT {self.dialect.epoch_us('min(m)')} AS origin FROM ("
            "SELECT f.m FROM unnest(%s::integer[]) AS u(sid) CROSS JOIN LATERAL (SELECT x.observed_at AS m "
            f"FROM samples x WHERE x.sid = u.sid AND x.observed_at IS NOT NULL AND {value}{end_o} "
            "ORDER BY x.observed_at LIMIT 1) f "
            "UNION ALL SELECT f.m FROM untimed_series u CROSS JOIN LATERAL (SELECT x.t AS m "
            f"FROM samples x WHERE x.sid = u.sid AND x.observed_at IS NULL AND {value}{end_t} "
            "ORDER BY x.t LIMIT 1) f WHERE u.sid = ANY(%s::integer[])) z"
        )
        ids = int_array(sids)
        return sql, [ids, *end, *end, ids]

    def location_extents(self, ask: ExtentsNear) -> list[ExtentRow]:
        """From ``geo_extents`` (kept by the writers, see storage.postgres.extents): the
        candidates' boxes without reading a single position. Over many
        series the table is searched by box (GiST) and intersected here:
        ``sid = ANY`` of thousands of ids would be tested on every row."""
        sids, prefilter = ask.sids, ask.prefilter
        if not sids:
            return []
        cols = "sid, min_lon, min_lat, max_lon, max_lat"
        test, params = box_test(self.dialect, extent_prefilter(prefilter))
        if len(sids) <= MANY_SIDS:
            sql = f"SELECT {cols} FROM geo_extents WHERE sid = ANY(%s::integer[]) AND {test}"
            return [_new(ExtentRow, (*row, None, None)) for row in self._fetch(sql, [int_array(sids), *params])]
        if prefilter is None:
            rows = self._fetch(f"SELECT {cols} FROM geo_extents", [], pooled=False)  # the shared ledger's
        else:
            box = prefilter[1]
            rows = self._fetch(
                f"SELECT {cols} FROM geo_extents WHERE {_BOX} && box(point(%s, %s), point(%s, %s)) AND {test}",
                [box.min_lon, box.min_lat, box.max_lon, box.max_lat, *params],
            )
        wanted = sids if isinstance(sids, (set, frozenset, dict)) else set(sids)
        return [_new(ExtentRow, (*row, None, None)) for row in rows if row[0] in wanted]

    def first_locations(self, sids: Sequence[int]) -> list[FirstLocationRow]:
        """One index probe per series (``(sid, t)`` index, oldest first)."""
        if not sids:
            return []
        return as_first_locations(
            self._fetch(
                f"SELECT s.sid, {self.dialect.epoch_us('l.t')}, l.rid FROM unnest(%s::integer[]) AS s(sid) "
                "CROSS JOIN LATERAL (SELECT t, rid FROM samples x WHERE x.sid = s.sid "
                f"AND x.kind = {int(Kind.GEO)} AND x.geo IS NOT NULL ORDER BY x.t, x.rid LIMIT 1) l",
                [int_array(sids)],
            )
        )

    def _raw_span(self, ask: SamplesIn) -> tuple[int, int] | None:
        """Two ``(sid, t)`` index probes per series (its first and last sample
        in the window) instead of reading the window."""
        d = self.dialect
        window, params = "", []
        if ask.time.start is not None:
            window += " AND x.t >= %s"
            params.append(d.time_value(ask.time.start))
        if ask.time.end is not None:
            window += " AND x.t <= %s"
            params.append(d.time_value(ask.time.end))
        sql = (
            f"SELECT {d.epoch_us('min(a.t)')}, {d.epoch_us('max(b.t)')} FROM unnest(%s::integer[]) AS s(sid) "
            f"CROSS JOIN LATERAL (SELECT x.t FROM samples x WHERE x.sid = s.sid{window} ORDER BY x.t LIMIT 1) a "
            f"CROSS JOIN LATERAL (SELECT x.t FROM samples x WHERE x.sid = s.sid{window} ORDER BY x.t DESC LIMIT 1) b"
        )
        rows = self._fetch(sql, [int_array(ask.sids), *params, *params])
        if not rows or rows[0][0] is None:
            return None
        return int(rows[0][0]), int(rows[0][1])

    def _location_seeds(self, sids: Sequence[int], before: datetime) -> tuple[str, list]:
        """The latest geo sample before ``before``: one index probe per series."""
        return (
            "SELECT l.sid, l.rid, l.t, l.kind, l.geo, l.min_lon, l.min_lat, l.max_lon, l.max_lat "
            "FROM unnest(%s::integer[]) AS s(s_sid) CROSS JOIN LATERAL ("
            "SELECT sid, rid, t, kind, geo, min_lon, min_lat, max_lon, max_lat FROM samples "
            f"WHERE sid = s.s_sid AND t < %s AND kind = {int(Kind.GEO)} AND geo IS NOT NULL "
            "ORDER BY t DESC, rid DESC LIMIT 1) l",
            [int_array(sids), self.dialect.time_value(before)],
        )

    def __init__(self, store: PostgresSource, partials_hours: int = 100_000):
        self._store = store
        # Hourly partials of aggregated series (storage.partials), checked
        # against the database's change counts before each use (migration 0011).
        self._hourly = HourlyPartials(partials_hours)
        self.dialect = PostgresDialect()
        self.catalog = SeriesCatalog(self._load_series, self._series_generation)
        self._generation: tuple[int, int] = (-1, -1)  # (own writer's series, series ever inserted)
        self._checked = float("-inf")
        # Runs the other parts of a split read; its thread starts at the first.
        self._helpers = ThreadPoolExecutor(AGGREGATE_PARTS - 1, thread_name_prefix="tsdb-pg-read")

    def series(self, ask: SeriesSelect) -> list[SeriesRef]:
        refs = self.catalog.select(ask.scope, ask.entities, ask.attrs)
        if not refs:
            self._checked = float("-inf")  # maybe created by another replica: count now
            refs = self.catalog.select(ask.scope, ask.entities, ask.attrs)
        return refs

    def _partials(self) -> HourlyPartials | None:
        return self._hourly if self._hourly.enabled else None

    def _series_versions(self, sids: Sequence[int]) -> dict[int, tuple[int, int]]:
        """Per series, (its block's change count, the TRUNCATE count) from
        ``series_changes`` (migration 0011): one short index read, whatever
        session, replica or SQL wrote the series since."""
        blocks = sorted({sid >> CHANGE_BLOCK_BITS for sid in sids})
        rows = self._fetch(
            "SELECT block, sum(n)::bigint FROM series_changes WHERE block = ANY(%s::integer[]) OR block = -1 "
            "GROUP BY block",
            [int_array(blocks)],
        )
        counts = dict(rows)
        truncated = counts.get(-1, 0)
        return {sid: (counts.get(sid >> CHANGE_BLOCK_BITS, 0), truncated) for sid in sids}

    def _series_generation(self) -> tuple[int, int]:
        """Changes when series were added; reads the counter only every
        ``SERIES_CHECK_S`` seconds unless this process created some."""
        own = self._store.series_created()  # grows after the writer's commits
        now = time.monotonic()
        if own == self._generation[0] and now - self._checked < SERIES_CHECK_S:
            return self._generation
        count = int(self._fetch("SELECT sum(n) FROM series_generation", [], pooled=False)[0][0])
        self._generation, self._checked = (own, count), now
        return self._generation

    def _load_series(self, position: int) -> list[tuple]:
        # No commit-ordered position exists here: load everything; the
        # catalog skips the series it already knows.
        return self._fetch(
            "SELECT sid, sid, tenant, service_path, entity_id, entity_type, attr, dataset_id FROM series ORDER BY sid",
            [],
            pooled=False,  # the shared catalog's, not one read's
        )

    def _fetch(
        self, sql: str, params: list, binary: bool = False, prepare: bool = True, pooled: bool = True
    ) -> list[tuple]:
        """All rows; ``binary``: in PostgreSQL's binary format, which parses
        faster where thousands of numeric rows come back. ``prepare=False``:
        planned for its parameters at every run; a prepared statement gets a
        generic plan after five runs, and for the aggregations that plan
        made one run in twenty take 20-50 ms instead of 6. ``pooled``: its
        rows count in the request's read pool (not a shared cache's load)."""
        check_database_allowed()
        try:
            with self._store.connection() as conn, conn.cursor(binary=binary) as cur:
                return budget.fetch_all(cur.execute(sql, params, prepare=prepare), pooled)
        except psycopg.OperationalError as exc:
            raise Unavailable(f"the database is not available: {exc}") from None

    def export_batches(self, ask: ExportRead) -> SampleBatches:
        """See ``BulkReader``. A server-side cursor (in its own transaction on
        a pooled connection, held until ``close()``) streams the sorted
        rows; each ``fetchmany`` becomes one batch, times as epoch
        microseconds (no Python ``datetime`` per row). PostgreSQL sorts on
        disk: ``sort_rows`` is not needed."""
        check_database_allowed()
        d = self.dialect
        sql, params = export_sql(d, ask.sids, ask.time, d.epoch_us("x.t"))
        batch_rows = ask.batch_rows
        batches = SampleBatches()
        res = batches.resources
        try:
            conn = res.enter_context(self._store.connection())
            res.enter_context(conn.transaction())  # a server-side cursor lives in a transaction
            cursor = res.enter_context(conn.cursor(name="tsdb_export"))
            cursor.execute(sql, params)
        except BaseException as exc:
            batches.close()
            if isinstance(exc, psycopg.OperationalError):
                raise Unavailable(f"the database is not available: {exc}") from None
            raise

        def read() -> Columns | None:
            rows = cursor.fetchmany(batch_rows)
            return rows_to_columns(rows) if rows else None

        batches.read = read
        return batches

    def _batches(self, sql: str, params: list, size: int) -> Iterator[list[tuple]]:
        """A server-side cursor in one transaction: one snapshot, bounded memory."""
        check_database_allowed()
        try:
            with self._store.connection() as conn, conn.transaction(), conn.cursor(name="tsdb_batches") as cur:
                cur.execute(sql, params)
                while rows := cur.fetchmany(size):
                    yield rows
        except psycopg.OperationalError as exc:
            raise Unavailable(f"the database is not available: {exc}") from None
