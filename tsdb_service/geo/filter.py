"""NGSIv2 geo-queries (``georel``, ``geometry``, ``coords``) as a frozen filter.

Parsing turns the three parameters into a ``GeoFilter`` or a 400 that says
what is wrong. Matching has two stages: a bounding box that SQL can apply to
the stored min/max columns (cheap, may over-match), then the exact predicate
with shapely, with distances measured on the WGS84 ellipsoid.
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property

import numpy as np
import orjson
import shapely
from shapely.geometry import LineString, Point, Polygon, box, shape
from shapely.geometry.base import BaseGeometry

from tsdb_service.core.errors import BadRequest
from tsdb_service.geo.geodesic import WGS84, geodesic_distance_m, geodesic_distances_m, radius_bbox

# JSON-style numbers only: float() would also take "1_0", "0x1p3" or "inf".
_NUMBER = re.compile(r"^\s*[+-]?(?:\d+(?:\.\d*)?|\.\d+)(?:[eE][+-]?\d+)?\s*$")

GEORELS = ("near", "coveredBy", "intersects", "equals", "disjoint")
GEOMETRIES = ("point", "line", "polygon", "box")
# What a geo-query filters (``geoScope``): each stored sample by the location
# its entity had then (QuantumLeap's rows), or whole entities by their latest.
SAMPLE, ENTITY = "sample", "entity"
GEO_SCOPES = (SAMPLE, ENTITY)


@dataclass(frozen=True, slots=True)
class BBox:
    min_lon: float
    min_lat: float
    max_lon: float
    max_lat: float


@dataclass(frozen=True)
class GeoFilter:
    georel: str
    shape: BaseGeometry  # lon/lat order
    max_distance: float | None = None  # metres, for near
    min_distance: float | None = None
    scope: str = SAMPLE

    @cached_property
    def prefilter(self) -> tuple[str, BBox] | None:
        """See ``box_prefilter``."""
        return box_prefilter(self.georel, self.shape, self.max_distance)

    def matches(self, geojson: str | dict) -> bool:
        """The exact predicate against one stored (normalised) geometry."""
        return relation_holds(self.georel, self.shape, geojson, self.max_distance, self.min_distance)

    def matches_array(self, lon: np.ndarray, lat: np.ndarray, geojson: np.ndarray, point: np.ndarray) -> np.ndarray:
        """The exact predicate for many stored geometries at once (shapely 2
        and pyproj array calls, no loop per geometry): where ``point`` is
        true the geometry is the point (lon, lat), elsewhere the GeoJSON text
        (None or unreadable: no match)."""
        out = np.zeros(len(point), dtype=bool)
        if not len(point):
            return out
        shapes = np.flatnonzero(~point)
        geoms = shapely.from_geojson(geojson[shapes].astype(object), on_invalid="ignore") if len(shapes) else None
        if self.georel == "near":
            distance = np.full(len(point), np.inf)
            at = np.flatnonzero(point)
            if len(at):
                _, _, metres = WGS84.inv(
                    np.full(len(at), self.shape.x), np.full(len(at), self.shape.y), lon[at], lat[at]
                )
                distance[at] = metres
            if geoms is not None:
                usable = ~shapely.is_missing(geoms) & ~shapely.is_empty(geoms)
                distance[shapes[usable]] = geodesic_distances_m(self.shape, geoms[usable])
            return np.isfinite(distance) & within_distance(distance, self.max_distance, self.min_distance)
        every = np.empty(len(point), dtype=object)
        every[point] = shapely.points(lon[point], lat[point])
        if geoms is not None:
            every[shapes] = geoms
        return relations_hold(self.georel, self.shape, every)

    def classify_extents(self, boxes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """For lon/lat boxes ``boxes`` (n x 4: min_lon, min_lat, max_lon,
        max_lat), whether every geometry inside each box surely matches, and
        whether none can. Neither: its geometries must be tested one by one."""
        n = len(boxes)
        if not n:
            return np.zeros(0, dtype=bool), np.zeros(0, dtype=bool)
        if self.georel == "near":
            return self._classify_near(boxes)
        extents = _boxes(boxes)
        shape = self.shape
        shapely.prepare(shape)
        covered = shapely.covers(shape, extents)
        apart = shapely.disjoint(shape, extents)
        if self.georel in ("coveredBy", "intersects"):
            return covered, apart
        if self.georel == "disjoint":
            return apart, covered
        return np.zeros(n, dtype=bool), ~shapely.covers(extents, shape)  # equals: a match contains the query

    def _classify_near(self, boxes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Distance bounds without a projection, for small boxes only (larger
        ones are tested sample by sample): no point of a box is nearer than
        its nearest corner minus its diagonal (triangle inequality; in a small
        box no point is farther from a corner than the opposite one) nor than
        the clamped point allows (below), and none is farther than its
        farthest corner (a parallel bends by well under the margin over a
        small box's edge). Close calls are left to the exact test."""
        n = len(boxes)
        lons = boxes[:, [0, 2, 0, 2]].ravel()
        lats = boxes[:, [1, 1, 3, 3]].ravel()
        _, _, corner = WGS84.inv(np.full(4 * n, self.shape.x), np.full(4 * n, self.shape.y), lons, lats)
        corner = np.asarray(corner).reshape(n, 4)
        _, _, diagonal = WGS84.inv(boxes[:, 0], boxes[:, 1], boxes[:, 2], boxes[:, 3])
        _, _, other = WGS84.inv(boxes[:, 0], boxes[:, 3], boxes[:, 2], boxes[:, 1])
        diag = np.maximum(diagonal, other)
        # The box point nearest in lon/lat (the query point clamped into the
        # box) is the nearest up to a slide of at most the diagonal along an
        # edge, which shortens a distance x by at most diag² / 2x.
        clamped_lon = np.clip(self.shape.x, boxes[:, 0], boxes[:, 2])
        clamped_lat = np.clip(self.shape.y, boxes[:, 1], boxes[:, 3])
        _, _, to_clamped = WGS84.inv(np.full(n, self.shape.x), np.full(n, self.shape.y), clamped_lon, clamped_lat)
        to_clamped = np.asarray(to_clamped)
        slide = diag**2 / (2 * np.maximum(to_clamped - diag, 1.0))
        nearest = np.maximum(corner.min(axis=1) - diag, to_clamped - slide)
        farthest = corner.max(axis=1)
        small = ((boxes[:, 2] - boxes[:, 0]) <= SMALL_BOX_DEG) & ((boxes[:, 3] - boxes[:, 1]) <= SMALL_BOX_DEG)
        sure = small.copy()
        none = np.zeros(n, dtype=bool)
        if self.max_distance is not None:
            sure &= farthest <= self.max_distance - MARGIN_M
            none |= small & (nearest > self.max_distance + MARGIN_M)
        if self.min_distance is not None:
            sure &= nearest >= self.min_distance + MARGIN_M
            none |= small & (farthest < self.min_distance - MARGIN_M)
        return sure, none


SMALL_BOX_DEG = 0.01  # ~1 km: boxes whose farthest point from the query point is a corner
MARGIN_M = 1.0


def _boxes(boxes: np.ndarray) -> np.ndarray:
    """Lon/lat boxes as geometries: a point or a segment where flat."""
    lo, hi = boxes[:, :2], boxes[:, 2:]
    flat = (lo == hi).any(axis=1)
    out = np.empty(len(boxes), dtype=object)
    out[~flat] = shapely.box(*boxes[~flat].T)
    if flat.any():
        # The diagonal of a flat box is the box: a segment, or a point.
        diagonal = shapely.linestrings(np.stack([lo[flat], hi[flat]], axis=1))
        point = (lo[flat] == hi[flat]).all(axis=1)
        diagonal[point] = shapely.points(lo[flat][point])
        out[flat] = diagonal
    return out


# Relations whose stored geometry must lie inside the query shape's box
# (NGSIv2 ``coveredBy`` is NGSI-LD's ``within``).
_WITHIN_BOX = frozenset({"coveredBy", "within", "equals"})


def box_prefilter(georel: str, query: BaseGeometry, max_distance: float | None) -> tuple[str, BBox] | None:
    """What SQL may check on a stored bounding box, for the NGSIv2 and the
    NGSI-LD relations alike: ("intersects", box), the stored box must
    overlap ``box``; ("within", box), it must lie inside ``box``; None, no
    safe prefilter (disjoint, minDistance-only near)."""
    if georel == "near":
        if max_distance is None:
            return None
        bbox = radius_bbox(query.x, query.y, max_distance)
        return None if bbox is None else ("intersects", BBox(*bbox))
    if georel == "disjoint":
        return None
    bounds = BBox(*query.bounds)
    return ("within", bounds) if georel in _WITHIN_BOX else ("intersects", bounds)


def relations_hold(
    georel: str,
    query: BaseGeometry,
    geoms: np.ndarray,
    max_distance: float | None = None,
    min_distance: float | None = None,
) -> np.ndarray:
    """``relation_holds`` for an array of stored geometries (shapely
    objects; None or empty never matches) in a few array calls: a loop per
    geometry costs ~20 µs each, and a geo-query over a window may test
    thousands of positions."""
    out = np.zeros(len(geoms), dtype=bool)
    usable = np.flatnonzero(~shapely.is_missing(geoms) & ~shapely.is_empty(geoms))
    if not len(usable):
        return out
    if georel == "near":
        out[usable] = within_distance(geodesic_distances_m(query, geoms[usable]), max_distance, min_distance)
        return out
    shapely.prepare(query)
    out[usable] = _RELATIONS[georel](query, geoms[usable])
    return out


def within_distance(distance: np.ndarray, max_distance: float | None, min_distance: float | None) -> np.ndarray:
    """``near``'s bounds on an array of distances (metres), both inclusive."""
    ok = np.ones(len(distance), dtype=bool)
    if max_distance is not None:
        ok &= distance <= max_distance
    if min_distance is not None:
        ok &= distance >= min_distance
    return ok


def geometries(geojson: Sequence[str]) -> np.ndarray:
    """Stored GeoJSON texts as shapely geometries, in one call (unreadable: None)."""
    return shapely.from_geojson(np.array(geojson, dtype=object), on_invalid="ignore")


# Each relation as an array call, query shape first (the names of both APIs:
# NGSIv2 ``coveredBy`` is NGSI-LD ``within``).
_RELATIONS = {
    "coveredBy": shapely.covers,
    "within": shapely.covers,
    "contains": lambda query, geoms: shapely.covers(geoms, query),
    "intersects": shapely.intersects,
    "disjoint": shapely.disjoint,
    "overlaps": shapely.overlaps,
    "equals": shapely.equals,
}


def relation_holds(
    georel: str,
    query: BaseGeometry,
    geojson: str | dict,
    max_distance: float | None = None,
    min_distance: float | None = None,
) -> bool:
    """The exact predicate between the query shape and one stored GeoJSON
    geometry (the relations of ``relations_hold``, without its array
    set-up: 7-8 µs a call); an unreadable or empty stored geometry never
    matches."""
    try:
        candidate = shape(orjson.loads(geojson) if isinstance(geojson, str) else geojson)
    except (ValueError, TypeError, AttributeError, KeyError, shapely.errors.GEOSException):
        return False
    if candidate.is_empty:
        return False
    if georel == "near":
        distance = geodesic_distance_m(query, candidate)
        return (max_distance is None or distance <= max_distance) and (min_distance is None or distance >= min_distance)
    return bool(_RELATIONS[georel](query, candidate))


def parse_geo(
    georel: str | None, geometry: str | None, coords: str | None, scope: str | None = None
) -> GeoFilter | None:
    """The three parameters travel together: all absent means no filter.
    ``scope`` (``geoScope``) says what is filtered: samples (default) or
    whole entities by their latest location."""
    given = {"georel": georel, "geometry": geometry, "coords": coords}
    if scope not in (None, "") and scope not in GEO_SCOPES:
        raise BadRequest(f"unknown geoScope {scope!r}: use one of {', '.join(GEO_SCOPES)}")
    if all(v in (None, "") for v in given.values()):
        if scope not in (None, ""):
            raise BadRequest("geoScope needs a geo-query: georel, geometry and coords")
        return None
    missing = [name for name, value in given.items() if value in (None, "")]
    if missing:
        raise BadRequest(f"geo-query needs georel, geometry and coords together; missing: {', '.join(missing)}")
    relation, max_d, min_d = _parse_georel(georel)  # type: ignore[arg-type]
    if geometry not in GEOMETRIES:
        raise BadRequest(f"unknown geometry {geometry!r}: use one of {', '.join(GEOMETRIES)}")
    points = _parse_coords(coords)  # type: ignore[arg-type]
    geom = _build_geometry(geometry, points)
    if relation == "near" and geometry != "point":
        raise BadRequest("georel=near needs geometry=point")
    return GeoFilter(relation, geom, max_d, min_d, scope or SAMPLE)


def _parse_georel(text: str) -> tuple[str, float | None, float | None]:
    parts = [p.strip() for p in text.split(";")]
    relation = parts[0]
    if relation not in GEORELS:
        raise BadRequest(f"unknown georel {relation!r}: use one of {', '.join(GEORELS)}")
    if relation != "near":
        if len(parts) > 1:
            raise BadRequest(f"georel={relation} takes no modifiers, got {';'.join(parts[1:])!r}")
        return relation, None, None
    limits: dict[str, float] = {}
    for modifier in parts[1:]:
        name, sep, value = modifier.partition(":")
        if not sep or name not in ("maxDistance", "minDistance"):
            raise BadRequest(f"bad near modifier {modifier!r}: use maxDistance:<metres> and/or minDistance:<metres>")
        if name in limits:
            raise BadRequest(f"{name} given twice")
        limits[name] = _metres(name, value)
    if not limits:
        raise BadRequest("georel=near needs maxDistance:<metres> and/or minDistance:<metres>")
    max_d, min_d = limits.get("maxDistance"), limits.get("minDistance")
    if max_d is not None and min_d is not None and min_d > max_d:
        raise BadRequest(f"minDistance {min_d:g} is greater than maxDistance {max_d:g}")
    return relation, max_d, min_d


def _metres(name: str, value: str) -> float:
    if not _NUMBER.match(value):
        raise BadRequest(f"{name} must be a number of metres, got {value!r}")
    metres = float(value)
    if not math.isfinite(metres) or metres < 0:
        raise BadRequest(f"{name} must be a non-negative number of metres, got {value!r}")
    return metres


def _parse_coords(text: str) -> list[tuple[float, float]]:
    """``lat,lon;lat,lon;...`` into (lon, lat) pairs."""
    points = []
    for i, pair in enumerate(text.split(";")):
        parts = pair.split(",")
        if len(parts) != 2:
            raise BadRequest(f"coords point {i + 1} ({pair!r}) must be 'lat,lon'")
        for label, part in (("latitude", parts[0]), ("longitude", parts[1])):
            if not _NUMBER.match(part):
                raise BadRequest(
                    f"coords point {i + 1} ({pair!r}) is not two numbers: {label} {part.strip()!r} is not a number"
                )
        lat, lon = float(parts[0]), float(parts[1])
        if not (math.isfinite(lat) and -90 <= lat <= 90):
            raise BadRequest(f"coords point {i + 1}: latitude {parts[0].strip()} is outside -90..90")
        if not (math.isfinite(lon) and -180 <= lon <= 180):
            raise BadRequest(f"coords point {i + 1}: longitude {parts[1].strip()} is outside -180..180")
        points.append((lon, lat))
    return points


def _build_geometry(kind: str, points: list[tuple[float, float]]) -> BaseGeometry:
    if kind == "point":
        if len(points) != 1:
            raise BadRequest(f"geometry=point needs exactly one 'lat,lon', got {len(points)}")
        return Point(points[0])
    if kind == "line":
        if len(points) < 2:
            raise BadRequest("geometry=line needs at least two points")
        return LineString(points)
    if kind == "box":
        if len(points) != 2:
            raise BadRequest("geometry=box needs exactly two opposite corners")
        (lon1, lat1), (lon2, lat2) = points
        if lon1 == lon2 or lat1 == lat2:
            raise BadRequest("geometry=box corners must differ in both latitude and longitude")
        return box(min(lon1, lon2), min(lat1, lat2), max(lon1, lon2), max(lat1, lat2))
    if len(points) < 4:
        raise BadRequest("geometry=polygon needs at least four points, the last equal to the first")
    if points[0] != points[-1]:
        raise BadRequest("geometry=polygon must be closed: the last point must equal the first")
    polygon = Polygon(points)
    if not polygon.is_valid:
        raise BadRequest(f"geometry=polygon is not a valid polygon: {shapely.is_valid_reason(polygon)}")
    return polygon
