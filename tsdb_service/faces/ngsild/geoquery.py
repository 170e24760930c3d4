"""NGSI-LD geo-queries (clause 4.10): ``georel``, ``geometry``,
``coordinates`` (GeoJSON order: longitude first), ``geoproperty``.

The reference geometry becomes a shapely shape; a stored location matches
with the same two stages as the NGSIv2 geo-queries (``tsdb_service.geo``):
a bounding box SQL can check on the stored min/max columns, then the exact
predicate, with distances geodesic on the WGS84 ellipsoid.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import orjson
import shapely
from shapely.geometry import shape
from shapely.geometry.base import BaseGeometry

from tsdb_service.core.errors import BadRequestData
from tsdb_service.geo.filter import BBox, box_prefilter, geometries, relations_hold

GEORELS = ("near", "within", "contains", "intersects", "equals", "disjoint", "overlaps")
GEOMETRIES = ("Point", "MultiPoint", "LineString", "MultiLineString", "Polygon", "MultiPolygon")
MAX_COORDINATES_CHARS = 100_000


@dataclass(frozen=True)
class LdGeoFilter:
    georel: str
    shape: BaseGeometry  # lon/lat
    max_distance: float | None = None
    min_distance: float | None = None

    @property
    def prefilter(self) -> tuple[str, BBox] | None:
        """("intersects" | "within", box) a stored bounding box must satisfy, or None."""
        return box_prefilter(self.georel, self.shape, self.max_distance)

    def matching(self, geojson: Sequence[str]) -> np.ndarray:
        """Whether each stored GeoJSON text satisfies the geo-query, as one
        boolean array (unreadable or empty: no)."""
        return relations_hold(self.georel, self.shape, geometries(geojson), self.max_distance, self.min_distance)


def parse_ld_geo(georel: str | None, geometry: str | None, coordinates) -> LdGeoFilter | None:
    """All three absent: no geo-query. ``coordinates`` is JSON text (query
    string) or an already-decoded array (a ``geoQ`` body)."""
    given = {"georel": georel, "geometry": geometry, "coordinates": coordinates}
    if all(v in (None, "") for v in given.values()):
        return None
    missing = [name for name, value in given.items() if value in (None, "")]
    if missing:
        raise BadRequestData(f"a geo-query needs georel, geometry and coordinates; missing: {', '.join(missing)}")
    relation, max_d, min_d = _georel(str(georel))
    if geometry not in GEOMETRIES:
        raise BadRequestData(f"unknown geometry {str(geometry)[:40]!r}: use one of {', '.join(GEOMETRIES)}")
    coords = _coordinates(coordinates)
    try:
        ref = shape({"type": geometry, "coordinates": coords})
    except (ValueError, TypeError, IndexError, AttributeError, shapely.errors.GEOSException) as exc:
        raise BadRequestData(f"coordinates do not make a {geometry}: {exc}") from None
    if ref.is_empty or not ref.is_valid:
        raise BadRequestData(f"coordinates do not make a valid {geometry}")
    minx, miny, maxx, maxy = ref.bounds
    if not (-180 <= minx <= maxx <= 180 and -90 <= miny <= maxy <= 90):
        raise BadRequestData("coordinates must be [longitude, latitude] within [-180, 180] and [-90, 90]")
    if relation == "near" and geometry != "Point":
        raise BadRequestData("georel=near needs geometry=Point")
    return LdGeoFilter(relation, ref, max_d, min_d)


def _georel(text: str) -> tuple[str, float | None, float | None]:
    parts = [p.strip() for p in text.split(";")]
    relation = parts[0]
    if relation not in GEORELS:
        raise BadRequestData(f"unknown georel {relation[:40]!r}: use one of {', '.join(GEORELS)}")
    max_d = min_d = None
    for modifier in parts[1:]:
        name, sep, value = modifier.partition("==")
        if not sep:
            name, sep, value = modifier.partition(":")  # NGSIv2 spelling, accepted
        if relation != "near" or name not in ("maxDistance", "minDistance"):
            raise BadRequestData(f"unexpected georel modifier {modifier[:40]!r}")
        try:
            metres = float(value)
        except ValueError:
            metres = math.nan
        if not math.isfinite(metres) or metres < 0:
            raise BadRequestData(f"{name} must be a non-negative number of metres, not {value[:40]!r}")
        if name == "maxDistance":
            max_d = metres
        else:
            min_d = metres
    if relation == "near" and max_d is None and min_d is None:
        raise BadRequestData("georel=near needs maxDistance or minDistance")
    return relation, max_d, min_d


def _coordinates(raw) -> list:
    if isinstance(raw, str):
        if len(raw) > MAX_COORDINATES_CHARS:
            raise BadRequestData("coordinates are too long")
        try:
            raw = orjson.loads(raw)
        except orjson.JSONDecodeError:
            raise BadRequestData("coordinates must be a JSON array such as [8.68, 49.41]") from None
    if not isinstance(raw, list) or not raw:
        raise BadRequestData("coordinates must be a non-empty JSON array")
    return raw
