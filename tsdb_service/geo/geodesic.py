"""Distances on the WGS84 ellipsoid.

QuantumLeap's PostgreSQL path turns metres into degrees with a flat
0.000009°/m, which overstates east-west distances away from the equator
(by 2x at 60°N). We measure with pyproj's ``Geod`` (Karney's algorithm).
For a point we use the exact inverse geodesic; for a line or area we
project it onto an azimuthal equidistant plane centred on the query point,
where distance from the centre equals the geodesic distance, after
densifying its edges (GeoJSON edges are straight in lon/lat, not geodesics).
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
import shapely
from pyproj import CRS, Geod, Transformer
from shapely.geometry import GeometryCollection, Point
from shapely.geometry.base import BaseGeometry

WGS84 = Geod(ellps="WGS84")
# Longest lon/lat edge piece projected as a straight line (~1 km or less).
EDGE_STEP_DEG = 0.01


def geodesic_distance_m(origin: Point, other: BaseGeometry) -> float:
    """Metres from ``origin`` to the nearest point of ``other`` (0 if it covers it)."""
    if other.geom_type == "Point":
        _, _, metres = WGS84.inv(origin.x, origin.y, other.x, other.y)
        return float(metres)
    if other.covers(origin):
        return 0.0
    to_plane = _aeqd(round(origin.x, 9), round(origin.y, 9))
    # GeoJSON edges are straight in lon/lat; the plane bends them. Densify
    # them first so every piece is short enough to stay straight there too.
    # Not covered, so the nearest point is on the outline; measuring to the
    # outline also avoids areas that wrap the plane's edge (the antipode).
    outline = _outline(other)
    if outline.length == 0:  # a line whose points coincide: GEOS cannot segmentize it
        outline = outline.envelope
    projected = shapely.transform(shapely.segmentize(outline, EDGE_STEP_DEG), to_plane, interleaved=False)
    return float(projected.distance(Point(0.0, 0.0)))


def geodesic_distances_m(origin: Point, geoms: np.ndarray) -> np.ndarray:
    """``geodesic_distance_m`` for an array of geometries at once (shapely's
    array functions: one projection for all of them, no loop per geometry)."""
    out = np.zeros(len(geoms))
    if not len(geoms):
        return out
    points = shapely.get_type_id(geoms) == 0
    if points.any():
        xs, ys = shapely.get_x(geoms[points]), shapely.get_y(geoms[points])
        _, _, metres = WGS84.inv(np.full(len(xs), origin.x), np.full(len(xs), origin.y), xs, ys)
        out[points] = metres
    others = np.flatnonzero(~points & ~shapely.covers(geoms, origin))
    if len(others):
        to_plane = _aeqd(round(origin.x, 9), round(origin.y, 9))
        outlines = _outlines(geoms[others])
        # A line whose points all coincide is a point (GEOS cannot segmentize it).
        flat = shapely.length(outlines) == 0
        outlines[flat] = shapely.envelope(outlines[flat])
        projected = shapely.transform(shapely.segmentize(outlines, EDGE_STEP_DEG), to_plane, interleaved=False)
        out[others] = shapely.distance(projected, Point(0.0, 0.0))
    return out


def _outlines(geoms: np.ndarray) -> np.ndarray:
    """``_outline`` of each: areas by their boundary (one array call),
    collections part by part (rare)."""
    kinds = shapely.get_type_id(geoms)
    out = geoms.copy()
    areas = (kinds == 3) | (kinds == 6)  # Polygon, MultiPolygon
    out[areas] = shapely.boundary(geoms[areas])
    for i in np.flatnonzero(kinds == 7):  # GeometryCollection
        out[i] = _outline(geoms[i])
    return out


def _outline(geom: BaseGeometry) -> BaseGeometry:
    if geom.geom_type in ("Polygon", "MultiPolygon"):
        return geom.boundary
    if geom.geom_type == "GeometryCollection":
        return GeometryCollection([_outline(part) for part in geom.geoms])
    return geom


@lru_cache(maxsize=256)
def _aeqd(lon: float, lat: float):
    crs = CRS.from_proj4(f"+proj=aeqd +lat_0={lat} +lon_0={lon} +ellps=WGS84 +units=m")
    return Transformer.from_crs("EPSG:4326", crs, always_xy=True).transform


def radius_bbox(lon: float, lat: float, metres: float) -> tuple[float, float, float, float] | None:
    """A lon/lat box containing every point within ``metres`` of (lon, lat),
    or None when it would wrap a pole or the antimeridian (no safe box)."""
    if metres <= 0:
        return (lon, lat, lon, lat)
    _, north, _ = WGS84.fwd(lon, lat, 0, metres)
    _, south, _ = WGS84.fwd(lon, lat, 180, metres)
    if north >= 89.9 or south <= -89.9 or north < lat or south > lat:
        return None
    # The widest east-west reach is at the circle's highest-|lat| edge, not at
    # the centre: measure along that parallel.
    widest_lat = north if abs(north) > abs(south) else south
    east, _, _ = WGS84.fwd(lon, widest_lat, 90, metres)
    west, _, _ = WGS84.fwd(lon, widest_lat, -90, metres)
    d_east, d_west = east - lon, lon - west
    if d_east <= 0 or d_west <= 0 or lon + d_east > 180 or lon - d_west < -180:
        return None
    # 1% margin: the geodesic circle is not exactly bounded by those points.
    margin_lon = 0.01 * max(d_east, d_west)
    margin_lat = 0.01 * (north - south)
    return (lon - d_west - margin_lon, south - margin_lat, lon + d_east + margin_lon, north + margin_lat)
