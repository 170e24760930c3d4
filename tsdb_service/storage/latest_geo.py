"""Each series' latest location, in memory (DuckDB only).

A geo-query asks "which entities are where, now?": the latest geo sample of
every candidate entity. From the sample tables that means ranking all
location samples of thousands of series per request; here it is a dict
look-up per series. Built with one query when the store opens, before the
writers start, then kept current by the writers after every commit (newest
by (time, row id) wins). A delete recomputes its series from the database;
an entry published after the delete (a row id above the delete's bound) is
never replaced by that older answer.

Queries bounded by ``toDate`` need the latest location *before* a time and
go to the database.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable, Iterable

from ..model import Kind

GEO = int(Kind.GEO)

# sid -> (t µs, rid, geojson, min_lon, min_lat, max_lon, max_lat)
Entry = tuple[int, int, str, float, float, float, float]


CELL_DEG = 0.05  # grid cell edge (~5 km): a near-1 km query reads a few cells
MAX_CELLS = 64  # geometries covering more cells are checked on every query


def _cells(mnlon: float, mnlat: float, mxlon: float, mxlat: float) -> list[tuple[int, int]] | None:
    """Grid cells a box overlaps, or None when it is too large to index."""
    x0, x1 = math.floor(mnlon / CELL_DEG), math.floor(mxlon / CELL_DEG)
    y0, y1 = math.floor(mnlat / CELL_DEG), math.floor(mxlat / CELL_DEG)
    if (x1 - x0 + 1) * (y1 - y0 + 1) > MAX_CELLS:
        return None
    return [(x, y) for x in range(x0, x1 + 1) for y in range(y0, y1 + 1)]


class LatestGeo:
    """Latest location per series, with a uniform grid over their boxes so a
    bounded query looks at the series in the cells it overlaps, not all."""

    def __init__(self, rows: Iterable[tuple]):
        self._lock = threading.Lock()
        self._latest: dict[int, Entry] = {}
        self._grid: dict[tuple[int, int], set[int]] = {}
        self._large: set[int] = set()
        for row in rows:
            self._put(row[0], tuple(row[1:]))

    def _put(self, sid: int, entry: Entry | None) -> None:
        """Set (or with None remove) ``sid``'s entry and its grid cells."""
        old = self._latest.pop(sid, None)
        if old is not None:
            cells = _cells(*old[3:7])
            if cells is None:
                self._large.discard(sid)
            else:
                for cell in cells:
                    members = self._grid.get(cell)
                    if members is not None:
                        members.discard(sid)
                        if not members:
                            del self._grid[cell]
        if entry is None:
            return
        self._latest[sid] = entry
        cells = _cells(*entry[3:7])
        if cells is None:
            self._large.add(sid)
        else:
            for cell in cells:
                self._grid.setdefault(cell, set()).add(sid)

    def publish(self, cols: dict[str, list]) -> None:
        kinds = cols["kind"]
        if GEO not in kinds:
            return
        sids, ts, rids, geos = cols["sid"], cols["t"], cols["rid"], cols["geo"]
        with self._lock:
            latest = self._latest
            for i, kind in enumerate(kinds):
                if kind != GEO or geos[i] is None:
                    continue
                current = latest.get(sids[i])
                if current is None or (ts[i], rids[i]) > current[:2]:
                    self._put(sids[i], (ts[i], rids[i], geos[i], cols["min_lon"][i], cols["min_lat"][i],
                                        cols["max_lon"][i], cols["max_lat"][i]))

    def recompute(self, sids, upto_rid: int, load: Callable[[list[int]], list[tuple]]) -> None:
        """After a delete of rows up to ``upto_rid`` in ``sids``."""
        fresh = {row[0]: tuple(row[1:]) for row in load(list(sids))}
        with self._lock:
            for sid in sids:
                current = self._latest.get(sid)
                if current is not None and current[1] > upto_rid:
                    continue  # published after the delete: still the latest
                self._put(sid, fresh.get(sid))

    def matching(self, sids: Iterable[int], prefilter) -> list[tuple[int, str]]:
        """(sid, geojson) of the latest locations whose box passes ``prefilter``."""
        latest = self._latest
        out = []
        if prefilter is None:
            for sid in sids:
                entry = latest.get(sid)
                if entry is not None:
                    out.append((sid, entry[2]))
            return out
        how, box = prefilter
        within = how == "within"
        cells = _cells(box.min_lon, box.min_lat, box.max_lon, box.max_lat)
        if cells is not None:
            wanted = set(sids)
            with self._lock:
                near = set(self._large)
                for cell in cells:
                    near |= self._grid.get(cell, set())
            sids = [sid for sid in near if sid in wanted]
        for sid in sids:
            entry = latest.get(sid)
            if entry is None:
                continue
            _, _, geo, mnlon, mnlat, mxlon, mxlat = entry
            if within:
                ok = mnlon >= box.min_lon and mxlon <= box.max_lon and mnlat >= box.min_lat and mxlat <= box.max_lat
            else:
                ok = mxlon >= box.min_lon and mnlon <= box.max_lon and mxlat >= box.min_lat and mnlat <= box.max_lat
            if ok:
                out.append((sid, geo))
        return out
