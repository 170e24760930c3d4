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

import threading
from collections.abc import Callable, Iterable

from ..model import Kind

GEO = int(Kind.GEO)

# sid -> (t µs, rid, geojson, min_lon, min_lat, max_lon, max_lat)
Entry = tuple[int, int, str, float, float, float, float]


class LatestGeo:
    def __init__(self, rows: Iterable[tuple]):
        self._lock = threading.Lock()
        self._latest: dict[int, Entry] = {row[0]: tuple(row[1:]) for row in rows}

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
                    latest[sids[i]] = (ts[i], rids[i], geos[i], cols["min_lon"][i], cols["min_lat"][i],
                                       cols["max_lon"][i], cols["max_lat"][i])

    def recompute(self, sids, upto_rid: int, load: Callable[[list[int]], list[tuple]]) -> None:
        """After a delete of rows up to ``upto_rid`` in ``sids``."""
        fresh = {row[0]: tuple(row[1:]) for row in load(list(sids))}
        with self._lock:
            for sid in sids:
                current = self._latest.get(sid)
                if current is not None and current[1] > upto_rid:
                    continue  # published after the delete: still the latest
                if sid in fresh:
                    self._latest[sid] = fresh[sid]
                else:
                    self._latest.pop(sid, None)

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
