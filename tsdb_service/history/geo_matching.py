"""What a geo-query keeps: samples (default) or whole entities.

Sample semantics (QuantumLeap's, the default): a stored sample matches when
the location its entity had at that sample's time satisfies the relation.
That location is the entity's latest location sample at or before the
sample, by (time, row id): every attribute of one notification shares its
time index and row id, so a notification's own location counts for its
other attributes, and a notification without a location keeps the previous
one. So "the drone's temperature readings inside this polygon" are the
readings taken while it was inside, and a robot that drove through an area
and left still has its in-area samples. ``lastN``, ``limit``, ``offset`` and
aggregations apply to the matching samples (see ``history.geo_masks``).

Entity semantics (``geoScope=entity``): an entity matches when its *latest*
location satisfies the relation (the latest at or before ``toDate`` when
given), and its history is returned as the other parameters ask, matching
or not: "the latest N samples of the devices near X now".

The location is the entity's ``location`` attribute (as in QuantumLeap), or
else its first geo-typed attribute by name (one with a geometry stored at or
before ``toDate``). Only samples holding a geometry are positions: a null
location leaves the previous one in place. Stored geometries are GeoJSON in
lon/lat order; SQL prefilters by bounding box and shapely decides exactly.
"""

from __future__ import annotations

import threading
import weakref
from collections import OrderedDict
from dataclasses import dataclass
from operator import attrgetter

from tsdb_service.core.query import EntityFilter, Scope, SeriesRef, TimeRange
from tsdb_service.geo.filter import ENTITY, GeoFilter
from tsdb_service.read import HistoryReads
from tsdb_service.read.requests import LocationsIn, SeriesSelect

EntityKey = tuple[str, str, str]  # service path, entity type, entity id
LOCATION = "location"
# C-level getters: requests may name 10,000s of series; a Python function
# call per series would be most of a geo-query's cost.
entity_key = attrgetter("service_path", "entity_type", "entity_id")
_SID = attrgetter("sid")


def apply_geo(
    querier: HistoryReads, scope: Scope, entities: EntityFilter, refs: list[SeriesRef], geo: GeoFilter, time: TimeRange
) -> tuple[list[SeriesRef], HistoryReads]:
    """``(refs, querier)`` for the rest of the request: the series of the
    matching entities, and a querier whose sample reads keep only the
    matching samples (the same querier under entity semantics)."""
    sel = _selection(querier, scope, entities, refs)
    locations = sel.locations
    if sel.without:
        locations = {**locations, **_fallback_locations(querier, scope, entities, time, sel.without)}
    if geo.scope == ENTITY:
        matched = matching_entities(querier, locations, geo, time)
        return [r for r, key in zip(refs, map(entity_key, refs), strict=True) if key in matched], querier
    from tsdb_service.core.query import RowMask
    from tsdb_service.history.geo_masks import MaskedQuerier, sample_spans

    intervals, kept = {}, []
    for key, found in sample_spans(querier, locations, geo, time).items():
        for ref in sel.refs_by_key.get(key, ()):
            intervals[ref.sid] = found
            kept.append(ref)
    return kept, MaskedQuerier(querier, RowMask(intervals))


@dataclass(frozen=True, slots=True)
class _Selection:
    """What a geo-query needs to know about the series a request selected:
    the location series of their entities (sid -> entity), their series by
    entity, and the entities without a ``location`` attribute."""

    locations: dict[int, EntityKey]
    refs_by_key: dict[EntityKey, list[SeriesRef]]
    without: frozenset[EntityKey]


_MEMO_SIZE = 32
_memo: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
_memo_lock = threading.Lock()


def _selection(querier: HistoryReads, scope: Scope, entities: EntityFilter, refs: list[SeriesRef]) -> _Selection:
    """Built once per selection and reused while the catalog gives the same
    series (the key holds their ids), so a repeated query over 10,000
    entities does not re-key 20,000 series each time."""
    named = querier.series(SeriesSelect(scope, entities, [LOCATION]))
    # The series ids themselves: exact, and cheaper than any summary of them.
    key = (scope, entities, tuple([r.sid for r in refs]), tuple([r.sid for r in named]))
    with _memo_lock:
        cache = _memo.setdefault(querier, OrderedDict())
        found = cache.get(key)
        if found is not None:
            cache.move_to_end(key)
            return found
    keys = list(map(entity_key, refs))
    named_keys = list(map(entity_key, named))
    refs_by_key: dict[EntityKey, list[SeriesRef]] = {}
    for ref, k in zip(refs, keys, strict=True):
        refs_by_key.setdefault(k, []).append(ref)
    selection = _Selection(
        dict(zip(map(_SID, named), named_keys, strict=True)),
        refs_by_key,
        frozenset(refs_by_key.keys() - set(named_keys)),
    )
    with _memo_lock:
        cache[key] = selection
        while len(cache) > _MEMO_SIZE:
            cache.popitem(last=False)
    return selection


def _fallback_locations(
    querier: HistoryReads, scope: Scope, entities: EntityFilter, time: TimeRange, without: frozenset[EntityKey]
) -> dict[int, EntityKey]:
    """Entities without a ``location`` attribute: their first geo-typed one
    (with a geometry stored at or before ``toDate``), sid -> entity."""
    others = [r for r in querier.series(SeriesSelect(scope, entities)) if entity_key(r) in without]
    if not others:
        return {}
    latest = querier.latest_geometries(LocationsIn([r.sid for r in others], TimeRange(None, time.end)))
    located = {sid for sid, _ in latest}
    first: dict[EntityKey, SeriesRef] = {}
    for ref in others:
        if ref.sid in located:
            k = entity_key(ref)
            if k not in first or ref.attr < first[k].attr:
                first[k] = ref
    return {ref.sid: k for k, ref in first.items()}


def matching_entities(
    querier: HistoryReads, locations: dict[int, EntityKey], geo: GeoFilter, time: TimeRange
) -> set[EntityKey]:
    """Entity semantics: the entities whose latest location (at or before
    ``toDate``) matches ``geo``."""
    if not locations:
        return set()
    rows = querier.latest_geometries(LocationsIn(list(locations), TimeRange(None, time.end), geo.prefilter))
    return {locations[sid] for sid, geojson in rows if geo.matches(geojson)}
