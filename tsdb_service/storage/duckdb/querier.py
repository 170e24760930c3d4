"""History reads on the embedded DuckDB store.

All SQL comes from ``storage.sql`` (``DuckDBDialect``); this module supplies
a connection (the store's per-thread cursor), the series catalog's loader,
and the answers memory gives (tails, latest locations, extents, hourly
aggregate partials).

It never imports the store: the store hands itself in as a ``DuckDBSource``
(what a reader needs of it), so the dependency runs one way, store → querier.
"""

from __future__ import annotations

import bisect
import contextlib
from collections.abc import Iterator, Sequence
from datetime import UTC, datetime, timedelta
from typing import Protocol

import duckdb

from tsdb_service.core import budget
from tsdb_service.core.errors import Unavailable
from tsdb_service.core.query import (
    ExtentRow,
    FirstLocationRow,
    GeometryRow,
    LocationRow,
    RawRow,
    RowMask,
    TimeRange,
    WindowScan,
    box_passes,
)
from tsdb_service.core.timefmt import iso_ms_us as iso_ms
from tsdb_service.read.bulk import Columns, SampleBatches
from tsdb_service.read.off_loop import check_database_allowed
from tsdb_service.read.requests import ExportRead, ExtentsNear, LocationsIn, RowsRead
from tsdb_service.read.requests import WindowScan as WindowScanRead
from tsdb_service.storage.catalog import SeriesCatalog
from tsdb_service.storage.columns import to_micros
from tsdb_service.storage.duckdb.dialect import DuckDBDialect
from tsdb_service.storage.duckdb.latest_geo import Position, position
from tsdb_service.storage.duckdb.memory import DuckDBMemory
from tsdb_service.storage.duckdb.tail_cache import TailCache, TailRow
from tsdb_service.storage.partials import HourlyPartials
from tsdb_service.storage.sql import temporal
from tsdb_service.storage.sql.bulk import export_sql
from tsdb_service.storage.sql.dialect import GEO_KIND, series_time_filter
from tsdb_service.storage.sql.locations import LOCATION_COLUMNS, as_first_locations
from tsdb_service.storage.sql.querier import SqlQuerier


class DuckDBSource(Protocol):
    """What the querier reads through (``DuckDBStore`` is one). The pieces of
    ``memory`` (tails, latest locations, partials) are looked up at each
    use: a reopen replaces them."""

    memory: DuckDBMemory

    def cursor(self) -> duckdb.DuckDBPyConnection: ...

    def reading(self) -> contextlib.AbstractContextManager[None]: ...

    def notice(self, exc: BaseException) -> str | None: ...

    def series_generation(self) -> int: ...


# DuckDB appends committed rows in commit order, so ``rowid`` only grows for
# an insert-only table (series ids do not: several writers allocate them).
# lastN over more series than this goes to the database in one query.
TAIL_MAX_SERIES = 64
PER_SERIES_BRANCHES = 64  # NGSI-LD matching: most series read as one UNION ALL branch each
# The two halves of ``samples_all``: the sorted table and the recent commits.
SORTED, HOT = "samples", "samples_hot"

_EPOCH = datetime(1970, 1, 1, tzinfo=UTC)
_LOAD_SERIES = (
    "SELECT rowid, sid, tenant, service_path, entity_id, entity_type, attr, dataset_id FROM series "
    "WHERE rowid > ? ORDER BY rowid"
)


class DuckDBQuerier(SqlQuerier):
    def __init__(self, store: DuckDBSource):
        self._store = store
        self.dialect = DuckDBDialect()
        self.catalog = SeriesCatalog(self._load_series, store.series_generation)

    def _load_series(self, after: int) -> list[tuple]:
        return self._fetch(_LOAD_SERIES, [after], pooled=False)  # the shared catalog's, not one read's

    def raw_rows(self, ask: RowsRead) -> list[RawRow]:
        """One attribute per row: try the in-memory tails first; under a geo
        mask, tails where they provably answer and one statement for the rest."""
        sids, time, newest_first, limit, offset = ask.sids, ask.time, ask.newest_first, ask.limit, ask.offset
        one_per_row, mask = ask.one_per_row, ask.mask
        if one_per_row and mask is not None and len(sids) <= TAIL_MAX_SERIES:
            return self._masked_rows(sids, time, newest_first, limit, offset, mask)
        if one_per_row and mask is None and (len(sids) == 1 or (newest_first and len(sids) <= TAIL_MAX_SERIES)):
            rows = self._from_tails(sids, time, newest_first, limit, offset)
            if rows is not None:
                return rows
        return super().raw_rows(ask)

    def _from_tails(
        self, sids: Sequence[int], time: TimeRange, newest_first: bool, limit: int, offset: int
    ) -> list[RawRow] | None:
        """Each series' tail holds its own newest ``offset + limit`` rows in the
        window, so the newest ``offset + limit`` of all of them are among those;
        rows order by (time, rid) as in SQL (rid is global)."""
        start = None if time.start is None else to_micros(time.start)
        end = None if time.end is None else to_micros(time.end)
        tail = self._store.memory.tail
        if len(sids) == 1:
            got = tail.rows(sids[0], self._load_tail, start, end, newest_first, limit, offset)
            if got is None:
                return None
            sid = sids[0]
            return [(sid, *row[1:]) for row in got]
        if offset + limit > tail.capacity:
            return self._from_deep_tails(sids, tail, start, end, limit, offset)
        merged: list[tuple] = []
        for sid in sids:
            got = tail.rows(sid, self._load_tail, start, end, True, offset + limit, 0)
            if got is None:
                return None
            merged.extend((row[0], row[1], sid, row) for row in got)
        return _window(merged, True, limit, offset)

    def _from_deep_tails(
        self, sids: Sequence[int], tail: TailCache, start: int | None, end: int | None, limit: int, offset: int
    ) -> list[RawRow] | None:
        """The newest ``offset + limit`` rows over many series, more than one
        tail holds: every series gives its whole cached window. A series
        whose window the tail holds only in part (``capacity`` rows, all in
        the window) hides only rows older than its oldest cached one; when
        that one is older than the ``offset + limit``-th newest cached row of
        all series, so is everything it hides, and the cached rows answer."""
        capacity = tail.capacity
        merged: list[tuple] = []
        cut = []  # per partly cached series: its oldest cached row's key
        for sid in sids:
            got = tail.rows(sid, self._load_tail, start, end, True, capacity, 0)
            if got is None:
                return None
            if len(got) >= capacity:
                cut.append((got[0][0], got[0][1], sid))
            merged.extend((row[0], row[1], sid, row) for row in got)
        wanted = offset + limit
        if cut:
            if len(merged) < wanted:
                return None
            merged.sort()
            threshold = merged[len(merged) - wanted][:3]
            if max(cut) >= threshold:
                return None
        return _window(merged, True, limit, offset)

    def _masked_rows(
        self, sids: Sequence[int], time: TimeRange, newest_first: bool, limit: int, offset: int, mask: RowMask
    ) -> list[RawRow]:
        """The rows a geo mask keeps, ``offset``/``limit`` over all series.
        Each series contributes at most its own first ``offset + limit`` kept
        rows in the wanted order. Newest first, from its tail when that
        provably holds them: the tails not cached are loaded together, with
        one statement (a geo-query's entities are scattered: one load each
        would cost more), so a repeated query near the same place reads
        nothing. The others' (oldest first, or deeper than a tail) from one
        SQL statement."""
        wanted = offset + limit
        merged: list[tuple] = []
        ask = []
        for sid in sids:
            if not mask.intervals.get(sid):
                continue
            kept = self._kept_from_tail(sid, time, wanted, mask) if newest_first else None
            if kept is None:
                ask.append(sid)
            else:
                merged.extend((row[0], row[1], sid, row) for row in kept)
        if ask and newest_first and wanted <= self._store.memory.tail.capacity:
            ask = self._kept_from_new_tails(ask, time, wanted, mask, merged)
        if ask:
            for row in self._masked_firsts(ask, time, newest_first, wanted, mask):
                merged.append((row[0], row[1], row[7], row[:7]))
        return _window(merged, newest_first, limit, offset)

    def _kept_from_tail(self, sid: int, time: TimeRange, wanted: int, mask: RowMask) -> list[tuple] | None:
        """The newest ``wanted`` rows ``mask`` keeps of a cached tail, when the
        tail provably holds them. None when not cached or not provable."""
        tail = self._store.memory.tail
        start = None if time.start is None else to_micros(time.start)
        end = None if time.end is None else to_micros(time.end)
        try:
            got = tail.rows(sid, _only_cached, start, end, True, tail.capacity, 0)
        except _NotCached:
            return None
        return _kept(sid, got, tail.capacity, wanted, mask)

    def _kept_from_new_tails(
        self, sids: list[int], time: TimeRange, wanted: int, mask: RowMask, merged: list[tuple]
    ) -> list[int]:
        """Load the tails of ``sids`` at once; the newest ``wanted`` kept rows
        of those that provably answer go to ``merged``. Returns the others."""
        tail = self._store.memory.tail
        start = None if time.start is None else to_micros(time.start)
        end = None if time.end is None else to_micros(time.end)
        rest = []
        for sid, got in tail.newest_many(sids, self._load_tails, start, end).items():
            kept = _kept(sid, got, tail.capacity, wanted, mask)
            if kept is None:
                rest.append(sid)
            else:
                merged.extend((row[0], row[1], sid, row) for row in kept)
        return rest

    def _load_tails(self, sids: list[int], n: int) -> dict[int, list[TailRow]]:
        """``_load_tail`` for many series in one statement (``_newest_rows``)."""
        d = self.dialect
        select = f"sid, {d.epoch_us('t')}, rid, {d.iso_ms('t')}, kind, num, txt, js"
        out: dict[int, list[TailRow]] = {}
        for sid, *row in self._newest_rows(sids, n, "sid, t, rid, kind, num, txt, js", select):
            out.setdefault(sid, []).append(tuple(row))
        return out

    def _newest_rows(self, sids: list[int], n: int, cols: str, select: str, where: str = "TRUE") -> list[tuple]:
        """The newest ``n`` rows passing ``where`` of each of ``sids`` (read
        as ``cols``, returned as ``select``), by series then newest first, in
        one statement: a ``sid = ?`` branch per series on the sorted table
        (each prunes it to the series' row groups) and one pass over the
        small hot table."""
        order = "ORDER BY t DESC, rid DESC"
        parts = [f"(SELECT {cols} FROM {SORTED} WHERE sid = ? AND {where} {order} LIMIT ?)"] * len(sids)
        params: list = [value for sid in sids for value in (sid, n)]
        in_hot, more = self.dialect.sid_filter(sids)
        parts.append(f"SELECT {cols} FROM {HOT} WHERE {in_hot} AND {where}")
        params += more
        sql = (
            f"SELECT {select} FROM ({' UNION ALL '.join(parts)}) u "
            f"QUALIFY row_number() OVER (PARTITION BY sid {order}) <= ? ORDER BY sid, t DESC, rid DESC"
        )
        return self._fetch(sql, [*params, n])

    def _masked_firsts(
        self, sids: Sequence[int], time: TimeRange, newest_first: bool, wanted: int, mask: RowMask
    ) -> list[tuple]:
        """The first ``wanted`` rows (in the request's order) that ``mask``
        keeps of ``sids``, as (t µs, rid, ISO time, kind, num, txt, js, sid).
        One ``sid = ?`` scan per series on the sorted table (each prunes it
        to the series' row groups) and one of the small hot table (an IN
        list of scattered ids would scan the whole sorted table), joined
        once with the mask's intervals: the mask as one relation plans in
        a fraction of the time of a predicate per interval."""
        d = self.dialect
        direction = "DESC" if newest_first else "ASC"
        cols = "t, rid, kind, num, txt, js, sid"
        parts, params = [], []
        for sid in sids:
            where, more = series_time_filter(d, [sid], time)
            parts.append(f"SELECT {cols} FROM {SORTED} WHERE {where}")
            params += more
        where, more = series_time_filter(d, sids, time)
        parts.append(f"SELECT {cols} FROM {HOT} WHERE {where}")
        params += more
        sql = (
            f"SELECT {d.epoch_us('t')}, rid, kind, num, txt, js, sid "
            f"FROM ({' UNION ALL '.join(parts)}) u JOIN {d.mask_relation()} ON m_sid = sid "
            f"WHERE {_IN_SPAN} ORDER BY t {direction}, rid {direction} LIMIT ?"
        )
        rows = self._fetch(sql, [*params, *RowMask({sid: mask.intervals[sid] for sid in sids}).arrays(), wanted])
        # The ISO text of the few rows kept, here: DuckDB would format every
        # sample of every series before the limit.
        return [(t, rid, iso_ms(t), kind, num, txt, js, sid) for t, rid, kind, num, txt, js, sid in rows]

    def location_extents(self, ask: ExtentsNear) -> list[ExtentRow]:
        """Memory only: where each series has ever been."""
        return self._store.memory.latest_geo.extents(ask.sids, ask.prefilter)

    def location_samples(self, ask: LocationsIn) -> list[LocationRow]:
        """From the tracks memory holds where they answer (``LatestGeo.
        positions``: the series it misses are loaded together and kept), so
        a repeated geo-query reads no positions: the samples in the window
        and the last one before it, as the SQL (``SqlQuerier``) returns them."""
        sids, time, prefilter = ask.sids, ask.time, ask.prefilter
        if not sids or len(sids) > TAIL_MAX_SERIES:
            return super().location_samples(ask)
        start = None if time.start is None else to_micros(time.start)
        end = None if time.end is None else to_micros(time.end)
        tracks = self._store.memory.latest_geo.positions(sorted(sids), start, self._load_positions)
        if tracks is None:
            return super().location_samples(ask)
        out: list[LocationRow] = []
        for sid in sorted(tracks):
            for t_us, rid, geojson, *corners in _in_window(tracks[sid], start, end):
                box = (corners[0], corners[1], corners[2], corners[3])
                if None in box:  # no box: SQL's tests are NULL, neither holds
                    ok = point = False
                else:
                    ok = prefilter is None or box_passes(prefilter[0], box, prefilter[1])
                    point = box[0] == box[2] and box[1] == box[3]
                out.append((sid, t_us, rid, ok, point, box[0], box[1], geojson if ok and not point else None))
        return out

    def _load_positions(self, sids: list[int], n: int) -> dict[int, list[Position]]:
        """The newest ``n`` positions of each of ``sids``, newest first, in
        one statement (``_newest_rows``)."""
        cols = "sid, t, rid, geo, min_lon, min_lat, max_lon, max_lat"
        select = f"sid, {self.dialect.epoch_us('t')}, rid, geo, min_lon, min_lat, max_lon, max_lat"
        located = f"kind = {GEO_KIND} AND geo IS NOT NULL"
        out: dict[int, list[Position]] = {}
        for sid, t_us, rid, geojson, *box in self._newest_rows(sids, n, cols, select, located):
            out.setdefault(sid, []).append(position(t_us, rid, geojson, tuple(box)))
        return out

    def _location_rows(self, sids: Sequence[int], time: TimeRange) -> tuple[str, list]:
        """One ``sid = ?`` branch per series on the sorted table (each prunes
        it to the series' row groups) and one over the hot table, where an
        IN list of scattered ids would scan the whole sorted table. With a
        window start, each part's latest position before it comes along:
        the later of the two is the series' (the other, older, only adds a
        true earlier position, whose interval ends before the window)."""
        if len(sids) > TAIL_MAX_SERIES:
            return super()._location_rows(sids, time)
        d = self.dialect
        located = f"kind = {GEO_KIND} AND geo IS NOT NULL"
        parts: list[str] = []
        params: list = []
        for sid in sids:
            where, more = series_time_filter(d, [sid], time)
            parts.append(f"SELECT {LOCATION_COLUMNS} FROM {SORTED} WHERE {where} AND {located}")
            params += more
        where, more = series_time_filter(d, sids, time)
        parts.append(f"SELECT {LOCATION_COLUMNS} FROM {HOT} WHERE {where} AND {located}")
        params += more
        if time.start is not None:
            before = d.time_value(time.start)
            for sid in sids:
                parts.append(
                    f"(SELECT {LOCATION_COLUMNS} FROM {SORTED} WHERE sid = ? AND t < ? AND {located} "
                    "ORDER BY t DESC, rid DESC LIMIT 1)"
                )
                params += [sid, before]
            where, more = d.sid_filter(sids)
            parts.append(
                f"SELECT {LOCATION_COLUMNS} FROM {HOT} WHERE {where} AND t < ? AND {located} "
                "QUALIFY row_number() OVER (PARTITION BY sid ORDER BY t DESC, rid DESC) = 1"
            )
            params += [*more, before]
        return " UNION ALL ".join(parts), params

    def first_locations(self, sids: Sequence[int]) -> list[FirstLocationRow]:
        """Only asked after a delete made a first position unknown: one
        branch per series (see ``_location_rows``)."""
        if not sids or len(sids) > TAIL_MAX_SERIES:
            return super().first_locations(sids)
        d = self.dialect
        parts = [
            f"(SELECT sid, {d.epoch_us('t')}, rid FROM {d.samples('sid, rid, t, kind, geo')} WHERE sid = ? "
            f"AND kind = {GEO_KIND} AND geo IS NOT NULL ORDER BY t, rid LIMIT 1)"
        ] * len(sids)
        return as_first_locations(self._fetch(" UNION ALL ".join(parts), list(sids)))

    def latest_geometries(self, ask: LocationsIn) -> list[GeometryRow]:
        """The latest locations come from memory unless bounded by ``toDate``."""
        if ask.time.start is None and ask.time.end is None:
            return self._store.memory.latest_geo.matching(ask.sids, ask.prefilter)
        return super().latest_geometries(ask)

    def _per_series(self, head: str, where: str, params: list, sids: Sequence[int]) -> list:
        """A few scattered series become one ``sid = ?`` branch each (UNION
        ALL): the table is sorted by series, so each branch reads its own
        row groups, where one IN list over far-apart ids scans all between."""
        if 1 < len(sids) <= PER_SERIES_BRANCHES and _scattered(sids):
            branch = f"{head} WHERE sid = ? AND {where}"
            return self._fetch(
                " UNION ALL ".join([branch] * len(sids)), [value for sid in sids for value in (sid, *params)]
            )
        return super()._per_series(head, where, params, sids)

    shared_scan = True

    def window_scan(self, ask: WindowScanRead) -> WindowScan:
        """One statement for them all (``temporal.scan_parts``): over many
        scattered series each would scan the sorted table's series ids
        (about 20 ms at 11M samples), and one scan answers every question.
        Few series: one statement each, whose per-series branches prune."""
        window, locations, tests = ask.window, ask.locations, ask.tests
        if locations is not None and not locations[0]:
            locations = None
        asked = [i for i, (sids, _) in enumerate(tests) if sids]
        total = sum(len(tests[i][0]) for i in asked) + (0 if locations is None else len(locations[0]))
        if len(asked) + (locations is not None) < 2 or total <= PER_SERIES_BRANCHES:
            return super().window_scan(WindowScanRead(window, locations, tests))
        head, where, params, sids, roles = temporal.scan_parts(
            self.dialect, window, locations, [tests[i] for i in asked]
        )
        sql = (
            f"{head} JOIN (SELECT unnest(?::INTEGER[]) AS w_sid, unnest(?::INTEGER[]) AS w_role) w "
            f"ON sid = w_sid WHERE sid BETWEEN ? AND ? AND {where}"
        )
        rows = self._fetch(sql, [sids, roles, min(sids), max(sids), *params])
        found: list[set[int]] = [set() for _ in tests]
        located = []
        for role, sid, geojson in rows:
            if role == 0:
                located.append((sid, geojson))
            else:
                found[asked[role - 1]].add(sid)
        return located, found

    def export_batches(self, ask: ExportRead) -> SampleBatches:
        """See ``BulkReader``. DuckDB sorts a result in memory up to its
        (machine-wide) memory limit, so the selection is read as consecutive
        time windows of about ``sort_rows`` samples each (split evenly over
        its time span), each sorted on its own: memory follows the window,
        not the export. Its result comes over as Arrow batches
        (``to_arrow_reader``) on a private cursor (the thread's own may be
        in use meanwhile)."""
        check_database_allowed()
        sids, time, batch_rows, sort_rows = ask.sids, ask.time, ask.batch_rows, ask.sort_rows
        batches = SampleBatches()
        try:
            cursor = self._store.cursor().cursor()
        except duckdb.ConnectionException as exc:
            raise Unavailable(f"the database is not available: {exc}") from None
        batches.resources.callback(cursor.close)
        try:
            windows = iter(self._export_windows(cursor, sids, time, sort_rows))
        except BaseException:
            batches.close()
            raise
        reader = None

        def read() -> Columns | None:
            nonlocal reader
            while True:
                if reader is None:
                    window = next(windows, None)
                    if window is None:
                        return None
                    sql, params = export_sql(self.dialect, sids, window, "x.t")
                    # a relation, not execute(): DuckDB 2 copies a DB-API result
                    # once more to hand it over as Arrow
                    reader = cursor.sql(sql, params=params).to_arrow_reader(batch_rows)
                try:
                    return reader.read_next_batch().columns
                except StopIteration:
                    reader = None

        batches.read = read
        return batches

    def _export_windows(
        self, cursor: duckdb.DuckDBPyConnection, sids: Sequence[int], time: TimeRange, sort_rows: int
    ) -> list[TimeRange]:
        """Inclusive windows covering the selection's samples, one per
        ``sort_rows`` of them (times are whole microseconds, so a window
        ending 1 µs before the next one starts leaves no gap)."""
        d = self.dialect
        where, params = series_time_filter(d, sids, time)
        # fetchall, not fetchone: the batches' relation runs on this cursor
        # next, and DuckDB refuses it while a result is left unfinished.
        [(first, last, count)] = cursor.execute(
            f"SELECT {d.epoch_us('min(t)')}, {d.epoch_us('max(t)')}, count(*) FROM {d.samples('sid, t')} WHERE {where}",
            params,
        ).fetchall()
        if not count:
            return []
        pieces = max(1, -(-count // sort_rows))
        step = -(-(last - first + 1) // pieces)
        return [TimeRange(_utc(start), _utc(min(start + step - 1, last))) for start in range(first, last + 1, step)]

    def _partials(self) -> HourlyPartials | None:
        """The store's hourly partials (``storage.partials``), kept current by
        its writer; off with several writer threads (row ids then do not grow
        in commit order, which a load's race check relies on)."""
        partials = self._store.memory.partials
        return partials if partials.enabled else None

    def _load_tail(self, sid: int, n: int) -> list[TailRow]:
        d = self.dialect
        return self._fetch(
            f"SELECT {d.epoch_us('t')}, rid, {d.iso_ms('t')}, kind, num, txt, js "
            f"FROM {d.samples('sid, rid, t, kind, num, txt, js')} WHERE sid = ? "
            "ORDER BY t DESC, rid DESC LIMIT ?",
            [sid, n],
        )

    def _fetch(self, sql: str, params: list, pooled: bool = True) -> list[tuple]:
        """Run a read; an invalidated database (disk full during a checkpoint)
        is a 503 while the store reopens it, not a 500. ``pooled``: its rows
        count in the request's read pool (not a shared cache's load)."""
        check_database_allowed()
        store = self._store
        try:
            with store.reading():
                return budget.fetch_all(store.cursor().execute(sql, params), pooled)
        except duckdb.Error as exc:
            unavailable = self._unavailable(exc)
            if unavailable is None:
                raise
            raise unavailable from None

    def _batches(self, sql: str, params: list, size: int) -> Iterator[list[tuple]]:
        """On a private cursor (the thread's own may be in use meanwhile)."""
        check_database_allowed()
        with self._errors():
            cur = self._store.cursor().cursor()
        try:
            with self._errors():
                cur.execute(sql, params)
            while True:
                with self._errors():
                    rows = cur.fetchmany(size)
                if not rows:
                    return
                yield rows
        finally:
            cur.close()

    def _unavailable(self, exc: duckdb.Error) -> Unavailable | None:
        """The 503 a DuckDB failure means, or None (then it is re-raised)."""
        if isinstance(exc, duckdb.ConnectionException):
            return Unavailable("the database is not available; retry later")
        if self._store.notice(exc) is not None:
            return Unavailable("the database is being reopened after a storage failure; retry later")
        return None

    @contextlib.contextmanager
    def _errors(self) -> Iterator[None]:
        try:
            yield
        except duckdb.Error as exc:
            unavailable = self._unavailable(exc)
            if unavailable is None:
                raise
            raise unavailable from None


class _NotCached(Exception):
    """A tail read that would have to load the tail."""


def _only_cached(sid: int, n: int) -> list[TailRow]:
    raise _NotCached


_MAX_RID = 2**63
# A joined mask row's interval holds the sample's (t, rid).
_IN_SPAN = "(t > m_t0 OR (t = m_t0 AND rid >= m_r0)) AND (m_t1 IS NULL OR t < m_t1 OR (t = m_t1 AND rid < m_r1))"


def _in_window(track: list[Position], start: int | None, end: int | None) -> list[Position]:
    """The positions of ``track`` (by (t, rid)) from ``start`` to ``end``
    (µs, inclusive), and the last one before ``start``."""
    lo = 0 if start is None else max(0, bisect.bisect_left(track, (start,)) - 1)
    hi = len(track) if end is None else bisect.bisect_right(track, (end, _MAX_RID))
    return track[lo:hi]


def _kept(sid: int, got: list[TailRow] | None, capacity: int, wanted: int, mask: RowMask) -> list[tuple] | None:
    """The newest ``wanted`` rows ``mask`` keeps of a tail's window ``got``
    (at most ``capacity`` rows, oldest first), when it provably holds them:
    all of the series' rows in the window, or at least ``wanted`` kept ones
    (every row not in the tail is older than all of those in it)."""
    if got is None:
        return None
    complete = len(got) < capacity  # fewer: the tail holds the whole window
    kept = mask.keep(sid, got)
    if not complete and len(kept) < wanted:
        return None
    return kept[max(0, len(kept) - wanted) :]


def _window(merged: list[tuple], newest_first: bool, limit: int, offset: int) -> list[RawRow]:
    """``offset``/``limit`` over (t, rid, sid, row) tuples, oldest first out."""
    merged.sort()
    if newest_first:
        stop = len(merged) - offset
        picked = merged[max(0, stop - limit) : max(0, stop)]
    else:
        picked = merged[offset : offset + limit]
    return [(sid, *row[1:]) for _, _, sid, row in picked]


def _scattered(sids: Sequence[int]) -> bool:
    """Far enough apart that the ids' span holds mostly other series."""
    return max(sids) - min(sids) + 1 > 4 * len(sids)


def _utc(micros: int) -> datetime:
    return _EPOCH + timedelta(microseconds=micros)
