"""Normalise every NGSI location encoding to one ``model.Geometry``.

NGSI has several ways to say "where": NGSIv2's simple-location types
(``geo:point``, ``geo:line``, ``geo:box``, ``geo:polygon``, all written as
``"lat, lon"`` text), ``geo:json`` and NGSI-LD ``GeoProperty`` (GeoJSON,
``[lon, lat]`` order). Geo queries must not care which one a device used, so
each is turned into GeoJSON in lon/lat order plus a representative point and a
bounding box (the box lets SQL prefilter before shapely runs the exact test).

Validity is checked here so storage can trust a ``Geometry``: coordinates are
finite numbers, longitudes within +-180 and latitudes within +-90, lines have
two positions, rings are closed with four. Anything else yields ``None``; the
caller then keeps the value as ordinary data rather than rejecting the
notification (see ``tsdb_service.parse.values``).
"""

from __future__ import annotations

import math
from typing import Any

import orjson
import shapely
from shapely.errors import GEOSException

from tsdb_service.core.model import Geometry

GEOMETRY_TYPES = frozenset(
    {
        "Point",
        "MultiPoint",
        "LineString",
        "MultiLineString",
        "Polygon",
        "MultiPolygon",
        "GeometryCollection",
    }
)
GEOJSON_TYPES = GEOMETRY_TYPES | {"Feature", "FeatureCollection"}

# Collections may nest; a small bound keeps hostile input from recursing deep.
_MAX_COLLECTION_DEPTH = 4


def looks_like_geojson(value: Any) -> bool:
    """Cheap shape test used before trusting an untyped dict to be a location."""
    if type(value) is not dict:
        return False
    kind = value.get("type")
    return type(kind) is str and kind in GEOJSON_TYPES


def from_ngsi(ngsi_type: str, value: Any) -> Geometry | None:
    """Geometry for a value of a geo type (``ngsi_type`` lower-cased).

    A dict is read as GeoJSON whatever the declared geo type, because agents
    often label GeoJSON ``geo:point``; a string under ``geo:json`` is parsed as
    GeoJSON text, which some IoT Agents send.
    """
    if type(value) is dict:
        return from_geojson(value)
    if ngsi_type == "geo:point":
        return _simple_point(value)
    if ngsi_type == "geo:line":
        return _simple_line(value)
    if ngsi_type == "geo:box":
        return _simple_box(value)
    if ngsi_type == "geo:polygon":
        return _simple_polygon(value)
    if type(value) is str:
        return _geojson_text(value)
    return None


def from_geojson(value: Any) -> Geometry | None:
    """Geometry for a GeoJSON geometry, Feature or FeatureCollection dict."""
    geometry = _geometry(value, 0)
    return None if geometry is None else _finish(geometry)


def parse_lat_lon(text: Any) -> list[float] | None:
    """``"lat, lon"`` (space optional) → ``[lon, lat]``, the GeoJSON order."""
    if type(text) is not str:
        return None
    parts = text.split(",")
    if len(parts) != 2:
        return None
    lat = _coordinate(parts[0])
    lon = _coordinate(parts[1])
    if lat is None or lon is None or not _in_range(lon, lat):
        return None
    return [lon, lat]


# --- NGSIv2 simple location ---------------------------------------------------


def _simple_point(value: Any) -> Geometry | None:
    position = parse_lat_lon(value)
    if position is None:
        return None
    return _finish({"type": "Point", "coordinates": position})


def _simple_line(value: Any) -> Geometry | None:
    positions = _lat_lon_list(value, 2)
    if positions is None:
        return None
    return _finish({"type": "LineString", "coordinates": positions})


def _simple_box(value: Any) -> Geometry | None:
    """Two opposite corners, in either order; a flat box is not an area."""
    corners = _lat_lon_list(value, 2)
    if corners is None or len(corners) != 2:
        return None
    (lon1, lat1), (lon2, lat2) = corners
    w, e = min(lon1, lon2), max(lon1, lon2)
    s, n = min(lat1, lat2), max(lat1, lat2)
    if w == e or s == n:
        return None
    ring = [[w, s], [e, s], [e, n], [w, n], [w, s]]
    return _finish({"type": "Polygon", "coordinates": [ring]})


def _simple_polygon(value: Any) -> Geometry | None:
    ring = _lat_lon_list(value, 4)
    if ring is None or ring[0] != ring[-1]:
        return None
    return _finish({"type": "Polygon", "coordinates": [ring]})


def _lat_lon_list(value: Any, minimum: int) -> list[list[float]] | None:
    if type(value) is not list or len(value) < minimum:
        return None
    out = []
    for item in value:
        position = parse_lat_lon(item)
        if position is None:
            return None
        out.append(position)
    return out


def _coordinate(text: str) -> float | None:
    """A finite float from text; rejects Python-only spellings like ``1_0``."""
    if "_" in text:
        return None
    try:
        number = float(text)
    except ValueError:
        return None
    return number if math.isfinite(number) else None


# --- GeoJSON ------------------------------------------------------------------


def _geojson_text(text: str) -> Geometry | None:
    try:
        value = orjson.loads(text)
    except orjson.JSONDecodeError:
        return None
    return from_geojson(value)


def _geometry(value: Any, depth: int) -> dict | None:
    """Validated, normalised GeoJSON geometry (only type and coordinates)."""
    if type(value) is not dict:
        return None
    kind = value.get("type")
    if type(kind) is not str:
        return None
    if kind == "Feature":
        return _geometry(value.get("geometry"), depth + 1) if depth < _MAX_COLLECTION_DEPTH else None
    if kind == "FeatureCollection":
        features = value.get("features")
        members = [f.get("geometry") if type(f) is dict else None for f in features] if type(features) is list else None
        return _collection(members, depth)
    if kind == "GeometryCollection":
        return _collection(value.get("geometries"), depth)
    reader = _COORDINATE_READERS.get(kind)
    coordinates = reader(value.get("coordinates")) if reader else None
    return None if coordinates is None else {"type": kind, "coordinates": coordinates}


def _collection(members: Any, depth: int) -> dict | None:
    if depth >= _MAX_COLLECTION_DEPTH or type(members) is not list or not members:
        return None
    geometries = []
    for member in members:
        geometry = _geometry(member, depth + 1)
        if geometry is None:
            return None
        geometries.append(geometry)
    return {"type": "GeometryCollection", "geometries": geometries}


def _position(value: Any) -> list[float] | None:
    """``[lon, lat]`` or ``[lon, lat, alt]`` of finite numbers within range."""
    if type(value) is not list or not 2 <= len(value) <= 3:
        return None
    out = []
    for number in value:
        kind = type(number)
        if kind is int:
            number = float(number)
        elif kind is not float or not math.isfinite(number):
            return None
        out.append(number)
    return out if _in_range(out[0], out[1]) else None


def _positions(value: Any, minimum: int = 1) -> list[list[float]] | None:
    if type(value) is not list or len(value) < minimum:
        return None
    out = []
    for item in value:
        position = _position(item)
        if position is None:
            return None
        out.append(position)
    return out


def _line(value: Any) -> list[list[float]] | None:
    return _positions(value, 2)


def _ring(value: Any) -> list[list[float]] | None:
    ring = _positions(value, 4)
    return ring if ring is not None and ring[0] == ring[-1] else None


def _many(reader):
    """Reader for a non-empty list of what ``reader`` accepts."""

    def read(value: Any) -> list | None:
        if type(value) is not list or not value:
            return None
        out = []
        for item in value:
            part = reader(item)
            if part is None:
                return None
            out.append(part)
        return out

    return read


_polygon = _many(_ring)

_COORDINATE_READERS = {
    "Point": _position,
    "MultiPoint": _positions,
    "LineString": _line,
    "MultiLineString": _many(_line),
    "Polygon": _polygon,
    "MultiPolygon": _many(_polygon),
}


def _in_range(lon: float, lat: float) -> bool:
    return -180.0 <= lon <= 180.0 and -90.0 <= lat <= 90.0


# --- representative point and bounds --------------------------------------------


def _finish(geometry: dict) -> Geometry | None:
    """Attach the representative point and bounds.

    Points are done by hand because they are by far the most common and need
    no GEOS round trip; everything else asks shapely for the centroid.
    """
    text = orjson.dumps(geometry).decode()
    if geometry["type"] == "Point":
        lon, lat = geometry["coordinates"][:2]
        return Geometry(text, lon, lat, lon, lat, lon, lat)
    try:
        shape = shapely.from_geojson(text)
        min_lon, min_lat, max_lon, max_lat = (float(b) for b in shapely.bounds(shape))
        centroid = shapely.centroid(shape)
        lon, lat = float(shapely.get_x(centroid)), float(shapely.get_y(centroid))
    except (GEOSException, ValueError, TypeError):
        return None
    if not math.isfinite(min_lon + min_lat + max_lon + max_lat):
        return None
    if not math.isfinite(lon + lat):
        # Degenerate shapes can have no centroid; the box centre still locates them.
        lon, lat = (min_lon + max_lon) / 2, (min_lat + max_lat) / 2
    return Geometry(text, lon, lat, min_lon, min_lat, max_lon, max_lat)
