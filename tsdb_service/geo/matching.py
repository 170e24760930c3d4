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
aggregations apply to the matching samples (see ``geo.masks``).

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

from ..history.query import EntityFilter, Scope, TimeRange
from ..storage.catalog import SeriesRef
from .filter import ENTITY, GeoFilter

EntityKey = tuple[str, str, str]  # service path, entity type, entity id
LOCATION = "location"


def entity_key(ref: SeriesRef) -> EntityKey:
    return (ref.service_path, ref.entity_type, ref.entity_id)


def apply_geo(querier, scope: Scope, entities: EntityFilter, refs: list[SeriesRef], geo: GeoFilter, time: TimeRange):
    """``(refs, querier)`` for the rest of the request: the series of the
    matching entities, and a querier whose sample reads keep only the
    matching samples (the same querier under entity semantics)."""
    candidates = {entity_key(r) for r in refs}
    locations = location_series(querier, scope, entities, time, candidates)
    if geo.scope == ENTITY:
        matched = matching_entities(querier, locations, geo, time)
        return [r for r in refs if entity_key(r) in matched], querier
    from .masks import MaskedQuerier, sample_mask

    mask = sample_mask(querier, locations, geo, time, refs)
    kept = [r for r in refs if r.sid in mask.intervals]
    return kept, MaskedQuerier(querier, mask)


def location_series(
    querier, scope: Scope, entities: EntityFilter, time: TimeRange, candidates: set[EntityKey]
) -> dict[EntityKey, SeriesRef]:
    """Each candidate entity's location series, for those that have one."""
    out: dict[EntityKey, SeriesRef] = {}
    for ref in querier.series(scope, entities, [LOCATION]):
        key = entity_key(ref)
        if key in candidates:
            out[key] = ref
    if len(out) == len(candidates):  # set operations in C: cheap on 10k entities
        return out
    without = candidates - out.keys()
    # Entities without a ``location`` attribute: their first geo-typed one.
    others = [r for r in querier.series(scope, entities, None) if entity_key(r) in without]
    if not others:
        return out
    located = {sid for sid, _geojson in querier.latest_geometries([r.sid for r in others], TimeRange(None, time.end), None)}
    for ref in sorted((r for r in others if r.sid in located), key=lambda r: r.attr, reverse=True):
        out[entity_key(ref)] = ref  # the first by name is written last
    return out


def matching_entities(querier, locations: dict[EntityKey, SeriesRef], geo: GeoFilter, time: TimeRange) -> set[EntityKey]:
    """Entity semantics: the entities whose latest location (at or before
    ``toDate``) matches ``geo``."""
    if not locations:
        return set()
    by_sid = {ref.sid: key for key, ref in locations.items()}
    rows = querier.latest_geometries(list(by_sid), TimeRange(None, time.end), geo.prefilter)
    return {by_sid[sid] for sid, geojson in rows if geo.matches(geojson)}
