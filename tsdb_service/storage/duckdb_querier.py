"""History reads on the embedded DuckDB store.

All SQL comes from ``storage.sql`` (``DuckDBDialect``); this module only
supplies a connection (the store's per-thread cursor) and the series
catalog's loader.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import duckdb

from ..errors import Unavailable
from .memory_only import check_database_allowed
from .catalog import SeriesCatalog
from .sql import DuckDBDialect, SqlQuerier
from .duckdb_store import to_micros

if TYPE_CHECKING:
    from .duckdb_store import DuckDBStore

# DuckDB appends committed rows in commit order, so ``rowid`` only grows for
# an insert-only table (series ids do not: several writers allocate them).
# lastN over more series than this goes to the database in one query.
TAIL_MAX_SERIES = 64

_LOAD_SERIES = (
    "SELECT rowid, sid, tenant, service_path, entity_id, entity_type, attr, dataset_id FROM series "
    "WHERE rowid > ? ORDER BY rowid"
)


class DuckDBQuerier(SqlQuerier):
    def __init__(self, store: DuckDBStore):
        self._store = store
        self.dialect = DuckDBDialect()
        self.catalog = SeriesCatalog(self._load_series, store.series_generation)

    def _load_series(self, after: int) -> list[tuple]:
        return self._fetch(_LOAD_SERIES, [after])

    def raw_rows(self, sids, time, *, newest_first, limit, offset, one_per_row, attrs_per_row=1, mask=None):
        """One attribute per row: try the in-memory tails first."""
        if one_per_row and (len(sids) == 1 or (newest_first and len(sids) <= TAIL_MAX_SERIES)):
            if mask is None:
                rows = self._from_tails(sids, time, newest_first, limit, offset)
            else:
                rows = self._from_masked_tails(sids, time, newest_first, limit, offset, mask)
            if rows is not None:
                return rows
        return super().raw_rows(
            sids, time, newest_first=newest_first, limit=limit, offset=offset,
            one_per_row=one_per_row, attrs_per_row=attrs_per_row, mask=mask,
        )  # fmt: skip

    def _from_tails(self, sids, time, newest_first, limit, offset) -> list[tuple] | None:
        """Each series' tail holds its own newest ``offset + limit`` rows in the
        window, so the newest ``offset + limit`` of all of them are among those;
        rows order by (time, rid) as in SQL (rid is global)."""
        start = None if time.start is None else to_micros(time.start)
        end = None if time.end is None else to_micros(time.end)
        tail = self._store.tail
        if len(sids) == 1:
            got = tail.rows(sids[0], self._load_tail, start, end, newest_first, limit, offset)
            return None if got is None else [(sids[0], *row[1:]) for row in got]
        merged = []
        for sid in sids:
            got = tail.rows(sid, self._load_tail, start, end, True, offset + limit, 0)
            if got is None:
                return None
            merged.extend((row[0], row[1], sid, row) for row in got)
        return _window(merged, True, limit, offset)

    def _from_masked_tails(self, sids, time, newest_first, limit, offset, mask) -> list[tuple] | None:
        """A geo mask keeps some of a tail's rows. The tail answers when it
        provably holds every kept row SQL would return: all of the series'
        rows in the window, or at least ``offset + limit`` kept rows (every
        uncached row is older than all cached ones), newest first only."""
        start = None if time.start is None else to_micros(time.start)
        end = None if time.end is None else to_micros(time.end)
        tail = self._store.tail
        capacity = tail.capacity
        merged = []
        for sid in sids:
            got = tail.rows(sid, self._load_tail, start, end, True, capacity, 0)
            if got is None:
                return None
            # Fewer than ``capacity`` rows: the tail holds the series' whole window.
            complete = len(got) < capacity
            kept = mask.keep(sid, got)
            if not complete and (not newest_first or len(kept) < offset + limit):
                return None
            if newest_first:
                kept = kept[max(0, len(kept) - offset - limit):]  # only these can be picked
            merged.extend((row[0], row[1], sid, row) for row in kept)
        return _window(merged, newest_first, limit, offset)

    def location_extents(self, sids, prefilter) -> list[tuple]:
        """From memory: where each series has ever been."""
        return self._store.latest_geo.extents(sids, prefilter)

    def location_candidates(self, sids, time, prefilter) -> list[int]:
        return self._store.latest_geo.ever_near(sids, prefilter)

    def _location_rows(self, sids, time) -> tuple[str, list]:
        """One ``sid = ?`` branch per series: each prunes the sorted table to
        the series' row groups, where an IN list of scattered ids scans all."""
        if len(sids) > TAIL_MAX_SERIES:
            return super()._location_rows(sids, time)
        parts, params = [], []
        for sid in sids:
            sql, more = super()._location_rows([sid], time)
            parts.append(sql)
            params += more
        return " UNION ALL ".join(parts), params

    def latest_geometries(self, sids, time, prefilter) -> list[tuple]:
        """The latest locations come from memory unless bounded by ``toDate``."""
        if time.start is None and time.end is None:
            return self._store.latest_geo.matching(sids, prefilter)
        return super().latest_geometries(sids, time, prefilter)

    def _load_tail(self, sid: int, n: int) -> list[tuple]:
        d = self.dialect
        return self._fetch(
            f"SELECT {d.epoch_us('t')}, rid, {d.iso_ms('t')}, kind, num, txt, js "
            f"FROM {d.samples('sid, rid, t, kind, num, txt, js')} WHERE sid = ? "
            "ORDER BY t DESC, rid DESC LIMIT ?",
            [sid, n],
        )

    def _fetch(self, sql: str, params: list) -> list[tuple]:
        """Run a read; an invalidated database (disk full during a checkpoint)
        is a 503 while the store reopens it, not a 500."""
        check_database_allowed()
        store = self._store
        try:
            with store.reading():
                return store.cursor().execute(sql, params).fetchall()
        except duckdb.ConnectionException:
            raise Unavailable("the database is not available; retry later") from None
        except duckdb.Error as exc:
            if store.notice(exc) is not None:
                raise Unavailable("the database is being reopened after a storage failure; retry later") from None
            raise


def _window(merged: list[tuple], newest_first: bool, limit: int, offset: int) -> list[tuple]:
    """``offset``/``limit`` over (t, rid, sid, row) tuples, oldest first out."""
    merged.sort()
    if newest_first:
        stop = len(merged) - offset
        picked = merged[max(0, stop - limit): max(0, stop)]
    else:
        picked = merged[offset: offset + limit]
    return [(sid, *row[1:]) for _, _, sid, row in picked]
