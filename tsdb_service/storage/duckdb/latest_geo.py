"""Each series' latest location and where it has ever been, in memory (DuckDB only).

Two questions a geo-query asks of every candidate entity, answered from
dict look-ups instead of ranking thousands of series' location samples:

* "where is it now?" (``geoScope=entity``): the latest geo sample of each
  series (newest by (time, row id) wins);
* "could any of its positions match?" (sample semantics): the bounding box
  of every geo sample the series ever had (its *extent*), and its first geo
  sample's (time, row id). Only entities whose extent overlaps the query's
  box can have a matching sample; of those, an entity whose whole extent
  matches (a robot working well inside the queried area) matched from its
  first position on, and only the others' location samples are read from
  the database.

Built with one query when the store opens, before the writers start, then
kept current by the writers after every commit. A delete recomputes the
latest entry of its series from the database; an entry published after the
delete (a row id above the delete's bound) is never replaced by that older
answer. Extents only grow: after a delete an extent may be larger than the
remaining samples, which only costs a few extra rows read (the exact answer
comes from the samples); the first position of a series touched by a delete
is forgotten, so its samples are always read.

Queries bounded by ``toDate`` need the latest location *before* a time and
go to the database.

A third, bounded, cache serves sample semantics' second step, "where was it
at each sample?": the newest ``TRACK_ROWS`` positions (geo samples) of
recently read location series (their *tracks*), least recently read out
first beyond ``TRACK_TOTAL`` positions. A track answers a query when it
provably holds what the database would return: every position of the
series, or, for a window starting after its oldest position, every one
in the window and the last before it (a position not in a track is older
than all in it). Loaded together for the series a query misses (one
statement), kept current by the same publish, dropped for series touched
by a delete. A load that raced a publish or a delete answers its own
query and is not kept.
"""

from __future__ import annotations

import math
import threading
from collections import OrderedDict
from collections.abc import Callable, Iterable

from tsdb_service.core.model import Kind
from tsdb_service.core.query import Bounds, Box, ExtentRow, GeometryRow, Prefilter, box_passes, extent_prefilter

GEO = int(Kind.GEO)

# Each series' newest geo sample, its extent and its first geo sample; with
# ``where`` ("AND sid IN ...") only some series'.
LATEST_GEO_SQL = (
    "SELECT sid, epoch_us(t), rid, geo, min_lon, min_lat, max_lon, max_lat, e_min_lon, e_min_lat, e_max_lon, "
    "e_max_lat, epoch_us(f_t), f_rid FROM (SELECT sid, t, rid, geo, min_lon, min_lat, max_lon, max_lat, "
    "row_number() OVER (PARTITION BY sid ORDER BY t DESC, rid DESC) AS rn, "
    "min(min_lon) OVER (PARTITION BY sid) AS e_min_lon, min(min_lat) OVER (PARTITION BY sid) AS e_min_lat, "
    "max(max_lon) OVER (PARTITION BY sid) AS e_max_lon, max(max_lat) OVER (PARTITION BY sid) AS e_max_lat, "
    "first_value(t) OVER (PARTITION BY sid ORDER BY t, rid) AS f_t, "
    "first_value(rid) OVER (PARTITION BY sid ORDER BY t, rid) AS f_rid "
    f"FROM samples_all WHERE kind = {GEO} AND geo IS NOT NULL {{where}}) latest WHERE rn = 1"
)

# sid -> (t µs, rid, geojson, min_lon, min_lat, max_lon, max_lat)
Entry = tuple[int, int, str, float, float, float, float]
_new = tuple.__new__


# A position: (t µs, rid, GeoJSON or None for a point, min_lon, min_lat, max_lon, max_lat).
Position = tuple[int, int, str | None, float, float, float, float]
TRACK_ROWS = 128  # newest positions kept per series
TRACK_TOTAL = 262_144  # positions cached in all (~200 bytes each)


CELL_DEG = 0.05  # grid cell edge (~5 km): a near-1 km query reads a few cells
MAX_CELLS = 64  # geometries covering more cells are checked on every query


def _cells(mnlon: float, mnlat: float, mxlon: float, mxlat: float) -> list[tuple[int, int]] | None:
    """Grid cells a box overlaps, or None when it is too large to index."""
    x0, x1 = math.floor(mnlon / CELL_DEG), math.floor(mxlon / CELL_DEG)
    y0, y1 = math.floor(mnlat / CELL_DEG), math.floor(mxlat / CELL_DEG)
    if (x1 - x0 + 1) * (y1 - y0 + 1) > MAX_CELLS:
        return None
    return [(x, y) for x in range(x0, x1 + 1) for y in range(y0, y1 + 1)]


class _Grid:
    """A uniform grid over one box per series: a bounded query looks at the
    series in the cells it overlaps, not all. Callers hold the lock."""

    def __init__(self) -> None:
        self.boxes: dict[int, Box] = {}
        self._cells: dict[tuple[int, int], set[int]] = {}
        self._large: set[int] = set()

    def put(self, sid: int, box: Box | None) -> None:
        """Set (or with None remove) ``sid``'s box. A box in the same cells
        as the one it replaces (a robot moving within a cell) only replaces it."""
        old = self.boxes.pop(sid, None)
        cells = None if box is None else _cells(*box)
        if old is not None:
            old_cells = _cells(*old)
            if box is not None and old_cells == cells:
                self.boxes[sid] = box
                return
            if old_cells is None:
                self._large.discard(sid)
            else:
                for cell in old_cells:
                    members = self._cells.get(cell)
                    if members is not None:
                        members.discard(sid)
                        if not members:
                            del self._cells[cell]
        if box is None:
            return
        self.boxes[sid] = box
        if cells is None:
            self._large.add(sid)
        else:
            for cell in cells:
                self._cells.setdefault(cell, set()).add(sid)

    def near(self, sids: Iterable[int], box: Bounds) -> list[int] | None:
        """Those of ``sids`` in the cells ``box`` overlaps (a superset of the
        overlapping ones), or None when the box is too large for the grid."""
        cells = _cells(box.min_lon, box.min_lat, box.max_lon, box.max_lat)
        if cells is None:
            return None
        near = set(self._large)
        for cell in cells:
            near |= self._cells.get(cell, set())
        wanted = sids if isinstance(sids, (set, frozenset, dict)) else set(sids)
        return [sid for sid in near if sid in wanted]


class LatestGeo:
    """Latest location and extent per series, each with a grid."""

    def __init__(self, rows: Iterable[tuple]):
        """``rows``: (sid, t µs, rid, geojson, its box (4), the series' extent
        (4), its first geo sample's t µs and rid)."""
        self._lock = threading.Lock()
        self._latest: dict[int, Entry] = {}
        self._grid = _Grid()
        self._extents = _Grid()
        self._first: dict[int, tuple[int, int] | None] = {}  # None: unknown (deleted)
        self._tracks: OrderedDict[int, _Track] = OrderedDict()
        self._track_total = 0
        self._seq = 0  # moves with every publish of geo samples and every delete
        for row in rows:
            self._put(row[0], tuple(row[1:8]))
            self._extents.put(row[0], tuple(row[8:12]))
            self._first[row[0]] = (row[12], row[13])

    def _put(self, sid: int, entry: Entry | None) -> None:
        """Set (or with None remove) ``sid``'s latest entry and its grid cells."""
        self._latest.pop(sid, None)
        if entry is not None:
            self._latest[sid] = entry
        self._grid.put(sid, None if entry is None else entry[3:7])

    def publish(self, cols: dict[str, list]) -> None:
        kinds = cols["kind"]
        if GEO not in kinds:
            return
        sids, ts, rids, geos = cols["sid"], cols["t"], cols["rid"], cols["geo"]
        mnlons, mnlats, mxlons, mxlats = cols["min_lon"], cols["min_lat"], cols["max_lon"], cols["max_lat"]
        with self._lock:
            self._seq += 1
            latest, extents = self._latest, self._extents
            for i, kind in enumerate(kinds):
                if kind != GEO or geos[i] is None:
                    continue
                sid = sids[i]
                box = (mnlons[i], mnlats[i], mxlons[i], mxlats[i])
                if sid in self._tracks:
                    self._track_insert(sid, position(ts[i], rids[i], geos[i], box))
                current = latest.get(sid)
                if current is None or (ts[i], rids[i]) > current[:2]:
                    self._put(sid, (ts[i], rids[i], geos[i], *box))
                extent = extents.boxes.get(sid)
                if extent is None:
                    self._first[sid] = (ts[i], rids[i])
                    extents.put(sid, box)
                elif box[0] < extent[0] or box[1] < extent[1] or box[2] > extent[2] or box[3] > extent[3]:
                    extents.put(
                        sid,
                        (
                            min(box[0], extent[0]),
                            min(box[1], extent[1]),
                            max(box[2], extent[2]),
                            max(box[3], extent[3]),
                        ),
                    )
                first = self._first.get(sid)
                if first is not None and (ts[i], rids[i]) < first:
                    self._first[sid] = (ts[i], rids[i])

    def recompute(self, sids, upto_rid: int, load: Callable[[list[int]], list[tuple]]) -> None:
        """After a delete of rows up to ``upto_rid`` in ``sids`` (extents stay)."""
        fresh = {row[0]: tuple(row[1:8]) for row in load(list(sids))}
        with self._lock:
            self._seq += 1
            for sid in sids:
                self._track_drop(sid)
                if sid in self._first:
                    self._first[sid] = None
                current = self._latest.get(sid)
                if current is not None and current[1] > upto_rid:
                    continue  # published after the delete: still the latest
                self._put(sid, fresh.get(sid))

    def matching(self, sids: Iterable[int], prefilter: Prefilter | None) -> list[GeometryRow]:
        """The latest locations whose box passes ``prefilter``."""
        latest = self._latest
        out = []
        if prefilter is None:
            for sid in sids:
                entry = latest.get(sid)
                if entry is not None:
                    out.append(_new(GeometryRow, (sid, entry[2])))
            return out
        how, box = prefilter
        with self._lock:
            near = self._grid.near(sids, box)
        for sid in sids if near is None else near:
            entry = latest.get(sid)
            if entry is not None and box_passes(how, entry[3:7], box):
                out.append(_new(GeometryRow, (sid, entry[2])))
        return out

    def ever_near(self, sids: Iterable[int], prefilter: Prefilter | None) -> list[int]:
        """Those of ``sids`` with a geo sample whose box may pass ``prefilter``
        (``core.query.extent_prefilter``). Without a prefilter: every located one."""
        extents = self._extents.boxes
        test = extent_prefilter(prefilter)
        if test is None:
            return [sid for sid in sids if sid in extents]
        how, box = test
        with self._lock:
            near = self._extents.near(sids, box)
        out = []
        for sid in sids if near is None else near:
            extent = extents.get(sid)
            if extent is not None and box_passes(how, extent, box):
                out.append(sid)
        return out

    def extents(self, sids: Iterable[int], prefilter: Prefilter | None) -> list[ExtentRow]:
        """(sid, min_lon, min_lat, max_lon, max_lat, first t µs | None, first
        rid | None) of those of ``sids`` that ``ever_near`` keeps."""
        near = self.ever_near(sids, prefilter)
        boxes, first = self._extents.boxes, self._first
        out = []
        for sid in near:
            box = boxes.get(sid)
            if box is not None:
                start = first.get(sid) or (None, None)
                out.append(_new(ExtentRow, (sid, *box, *start)))
        return out

    # -- positions of recently read series -----------------------------------------------

    def positions(
        self, sids: list[int], start_us: int | None, load: Callable[[list[int], int], dict[int, list[Position]]]
    ) -> dict[int, list[Position]] | None:
        """Per series of ``sids``, its cached positions by (t, rid), the
        missing ones from one ``load(missing, n)`` (per series its newest
        ``n`` positions, newest first). None when one of them cannot answer
        a window starting at ``start_us`` (None: all time; see the module)."""
        tracks: dict[int, _Track] = {}
        missing = []
        with self._lock:
            for sid in sids:
                track = self._tracks.get(sid)
                if track is None:
                    missing.append(sid)
                else:
                    self._tracks.move_to_end(sid)
                    tracks[sid] = _Track(list(track.rows), track.whole)
            seq = self._seq
        if missing:
            loaded = load(missing, TRACK_ROWS + 1)
            with self._lock:
                keep = self._seq == seq
                for sid in missing:
                    newest = loaded.get(sid, [])
                    track = _Track(newest[:TRACK_ROWS][::-1], len(newest) <= TRACK_ROWS)
                    tracks[sid] = track
                    if keep and track.rows and sid not in self._tracks:
                        self._tracks[sid] = _Track(list(track.rows), track.whole)
                        self._track_total += len(track.rows)
                while self._track_total > TRACK_TOTAL and self._tracks:
                    _, evicted = self._tracks.popitem(last=False)
                    self._track_total -= len(evicted.rows)
        if not all(track.answers(start_us) for track in tracks.values()):
            return None
        return {sid: track.rows for sid, track in tracks.items()}

    def _track_insert(self, sid: int, position: Position) -> None:
        """A published position into its cached track (callers hold the
        lock). One older than a partial track is not part of it; one
        already there (loaded with it) is skipped; beyond ``TRACK_ROWS``
        the oldest goes and the track is no longer the whole series."""
        track = self._tracks[sid]
        rows, key = track.rows, position[:2]
        if not track.whole and rows and key < rows[0][:2]:
            return
        at = len(rows)
        while at and rows[at - 1][:2] > key:
            at -= 1
        if at and rows[at - 1][:2] == key:
            return
        rows.insert(at, position)
        self._track_total += 1
        if len(rows) > TRACK_ROWS:
            del rows[0]
            track.whole = False
            self._track_total -= 1

    def _track_drop(self, sid: int) -> None:
        track = self._tracks.pop(sid, None)
        if track is not None:
            self._track_total -= len(track.rows)


class _Track:
    """A series' newest positions by (t, rid); ``whole``: all of them."""

    __slots__ = ("rows", "whole")

    def __init__(self, rows: list[Position], whole: bool):
        self.rows = rows
        self.whole = whole

    def answers(self, start_us: int | None) -> bool:
        """Holds every position from ``start_us`` on and the last before it."""
        return self.whole or (start_us is not None and bool(self.rows) and self.rows[0][0] < start_us)


def position(t_us: int, rid: int, geojson: str, box: tuple) -> Position:
    """A point keeps no text: its box is the point."""
    point = box[0] == box[2] and box[1] == box[3]
    return (t_us, rid, None if point else geojson, *box)
