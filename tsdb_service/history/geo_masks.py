"""Sample semantics: a geo-query as per-series time masks.

An entity's location is a step function of time: each location sample holds
from its (time, row id) until the next one. A geo-query is resolved once per
request into the intervals in which that location matched, then every read
keeps only the samples inside them (``query.RowMask``, a join against
bound arrays), so ordering, ``lastN``, ``limit``, ``offset`` and
aggregations run in the database on the matching samples only.

Resolving costs little because most entities are never near the query:

1. candidates: the entities whose location series' *extent* (the bounding
   box of every position it ever had: in memory on DuckDB, the
   ``geo_extents`` table on PostgreSQL) passes the query's box. The extent
   also settles most of them: one that lies wholly inside the query's region
   matched from its first position on (kept in memory on DuckDB, one index
   probe otherwise), one wholly outside never did;
2. the others' location samples in the window, plus the last one before it
   (SQL, or on DuckDB the positions memory keeps where they answer; each
   sample's box is tested first, so only those that pass are parsed);
3. the exact predicate for all of them at once (shapely 2 / pyproj arrays);
4. runs of consecutive matching samples become intervals.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from tsdb_service.core.query import AggregateRow, LatestRow, RawRow, RowMask, TimeRange
from tsdb_service.geo.filter import GeoFilter
from tsdb_service.read import HistoryReads
from tsdb_service.read.requests import AggregateRead, ExtentsNear, LocationsIn, RowsRead, SamplesIn

Span = tuple[int, int, int | None, int | None]  # t0 µs, rid0, t1 µs | None (open), rid1


def sample_spans(
    querier: HistoryReads, locations: dict[int, tuple], geo: GeoFilter, time: TimeRange
) -> dict[tuple, list[Span]]:
    """Entity -> the intervals in which its location matched, for the
    entities of ``locations`` (location series id -> entity) that matched."""
    spans: dict[int, list[Span]] = {}
    # The dict itself: backends test membership in it (no set of 10,000s built).
    read = _from_extents(querier, querier.location_extents(ExtentsNear(locations, geo.prefilter)), geo, spans)
    if read:
        spans.update(location_spans(querier.location_samples(LocationsIn(read, time, geo.prefilter)), geo))
    return {locations[sid]: found for sid, found in spans.items()}


def _from_extents(
    querier: HistoryReads, extents: Sequence[tuple], geo: GeoFilter, spans: dict[int, list[Span]]
) -> list[int]:
    """Decide what the extents decide: a series whose every position matches
    matched from its first one on (into ``spans``; a first position the
    backend does not keep is looked up, one index probe each); one whose
    positions cannot match is dropped. Returns the series to read."""
    if not extents:
        return []
    sid, *box, first_t, first_rid = zip(*extents, strict=True)
    every, none = geo.classify_extents(np.array(box, dtype=float).T)
    read = [s for s, settled in zip(sid, (every | none).tolist(), strict=True) if not settled]
    unknown = []
    for s in np.flatnonzero(every).tolist():
        if first_t[s] is None:
            unknown.append(sid[s])
        else:
            spans[sid[s]] = [(first_t[s], first_rid[s], None, None)]
    if unknown:
        for s, t_us, rid in querier.first_locations(unknown):
            spans[s] = [(int(t_us), int(rid), None, None)]
    return read


def location_spans(rows: list[tuple], geo: GeoFilter) -> dict[int, list[Span]]:
    """Per location series, the intervals in which its location matched.
    ``rows`` are ``location_samples`` rows, ordered by (sid, t, rid)."""
    if not rows:
        return {}
    sid_col, t_col, rid_col, ok_col, point, lon, lat, geojson = zip(*rows, strict=True)
    sid = np.fromiter(sid_col, np.int64, len(rows))
    t_us = np.fromiter(t_col, np.int64, len(rows))
    rid = np.fromiter(rid_col, np.int64, len(rows))
    ok = np.fromiter(ok_col, bool, len(rows))
    match = np.zeros(len(rows), dtype=bool)
    test = np.flatnonzero(ok)
    if len(test):
        match[test] = geo.matches_array(
            np.asarray(lon, dtype=float)[test],
            np.asarray(lat, dtype=float)[test],
            np.asarray(geojson, dtype=object)[test],
            np.fromiter(point, bool, len(rows))[test],
        )
    return _runs(sid, t_us, rid, match)


def _runs(sid: np.ndarray, t_us: np.ndarray, rid: np.ndarray, match: np.ndarray) -> dict[int, list[Span]]:
    """Runs of consecutive matching samples of one series, each from its
    first sample to the series' next (non-matching) sample, or open."""
    same_next = np.zeros(len(sid), dtype=bool)
    same_next[:-1] = sid[1:] == sid[:-1]
    next_match = np.zeros(len(sid), dtype=bool)
    next_match[:-1] = match[1:]
    prev_match = np.zeros(len(sid), dtype=bool)
    prev_match[1:] = match[:-1] & same_next[:-1]
    firsts = np.flatnonzero(match & ~prev_match)
    lasts = np.flatnonzero(match & ~(same_next & next_match))
    out: dict[int, list[Span]] = {}
    for first, last in zip(firsts.tolist(), lasts.tolist(), strict=True):
        span: Span
        if same_next[last]:
            span = (int(t_us[first]), int(rid[first]), int(t_us[last + 1]), int(rid[last + 1]))
        else:
            span = (int(t_us[first]), int(rid[first]), None, None)
        out.setdefault(int(sid[first]), []).append(span)
    return out


class MaskedQuerier:
    """A querier whose sample reads keep only the samples ``mask`` keeps;
    everything else is the wrapped querier's."""

    def __init__(self, inner: HistoryReads, mask: RowMask):
        self._inner = inner
        self.mask = mask

    def __getattr__(self, name: str):
        return getattr(self._inner, name)

    def raw_rows(self, ask: RowsRead) -> list[RawRow]:
        return self._inner.raw_rows(replace(ask, mask=self.mask))

    def aggregate(self, ask: AggregateRead) -> list[AggregateRow]:
        return self._inner.aggregate(replace(ask, mask=self.mask))

    def latest_index(self, ask: SamplesIn) -> list[LatestRow]:
        return self._inner.latest_index(replace(ask, mask=self.mask))

    def count(self, ask: SamplesIn) -> int:
        return self._inner.count(replace(ask, mask=self.mask))
