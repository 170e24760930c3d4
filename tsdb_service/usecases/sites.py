"""Where the use cases happen: entity ids, tenants and real-world coordinates.

Everything that the simulators, the request collection, the subscriptions and
the tests must agree on lives here, so a query about "sensors near the field
centre" and the simulator placing those sensors cannot drift apart.

Coordinates are (lat, lon) in decimal degrees, the order NGSI ``coords`` use;
GeoJSON values are built with :func:`geo_point` (lon, lat order).
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

from pyproj import Geod

WGS84 = Geod(ellps="WGS84")


@dataclass(frozen=True)
class Tenancy:
    """The Fiware-Service / Fiware-ServicePath a use case is stored under."""

    service: str
    service_path: str


# -- Bosch lawnmower: a garden on the Renningen research campus ----------------
LAWNMOWER = Tenancy("lawnmower", "/bosch")
LAWNMOWER_ID = "urn:ngsiv2:ROS2System:Lawnmower01"
# The garden's south-west corner, where the dock is; local x points east, y north.
GARDEN_ORIGIN = (48.765310, 8.934560)
GARDEN_WIDTH_M = 16.0
GARDEN_DEPTH_M = 10.0

# -- PIAP smart warehouse: Warsaw ------------------------------------------------
WAREHOUSE = Tenancy("warehouse", "/piap")
WAREHOUSE_ID = "urn:ngsiv2:ROS2System:PiapWarehouse01"
WAREHOUSE_ROBOT_ID = "urn:ngsiv2:ROS2System:PiapRobot01"
DOOR_OPEN_DISTANCE_M = 0.6

# -- eProsima drone: fields north-east of Tres Cantos, Madrid ---------------------
DRONE = Tenancy("drone", "/eprosima")
DRONE_ID = "urn:ngsiv2:ROS2System:Drone01"
SENSOR_TYPE = "RemoteSensor"
DRONE_HOME = (40.603000, -3.693000)
SENSOR_FIELD_CENTRE = (40.608094, -3.686316)
# (id, (lat, lon), mission priority): the priorities are the joint use case's.
SENSORS: tuple[tuple[str, tuple[float, float], float], ...] = (
    ("urn:ngsiv2:RemoteSensor:Sensor01", (40.609535, -3.689590), 0.075),
    ("urn:ngsiv2:RemoteSensor:Sensor02", (40.610209, -3.685306), 0.075),
    ("urn:ngsiv2:RemoteSensor:Sensor03", (40.608657, -3.682127), 0.075),
    ("urn:ngsiv2:RemoteSensor:Sensor04", (40.606690, -3.685252), 0.175),
    ("urn:ngsiv2:RemoteSensor:Sensor05", (40.605754, -3.688088), 0.100),
    ("urn:ngsiv2:RemoteSensor:Sensor06", (40.607859, -3.688061), 0.200),
    ("urn:ngsiv2:RemoteSensor:Sensor07", (40.609786, -3.687124), 0.125),
    ("urn:ngsiv2:RemoteSensor:Sensor08", (40.607824, -3.685702), 0.175),
)
SENSOR_IDS = tuple(sensor_id for sensor_id, _, _ in SENSORS)
MISSION_PRIORITIES = tuple(priority for _, _, priority in SENSORS)
# The sensor field: a closed ring (lat, lon) around all sensors, home outside it.
SENSOR_FIELD = (
    (40.6050, -3.6905),
    (40.6110, -3.6905),
    (40.6110, -3.6812),
    (40.6050, -3.6812),
    (40.6050, -3.6905),
)


def geo_point(lat: float, lon: float) -> dict:
    """A GeoJSON Point, lon/lat order, rounded to ~1 cm as a GNSS receiver reports."""
    return {"type": "Point", "coordinates": [round(lon, 7), round(lat, 7)]}


def offset(origin: tuple[float, float], east_m: float, north_m: float) -> tuple[float, float]:
    """(lat, lon) of a point given in local metres from ``origin``, on the ellipsoid."""
    distance = math.hypot(east_m, north_m)
    if distance == 0:
        return origin
    azimuth = math.degrees(math.atan2(east_m, north_m))
    lon, lat, _ = WGS84.fwd(origin[1], origin[0], azimuth, distance)
    return lat, lon


def distance_m(a: tuple[float, float], b: tuple[float, float]) -> float:
    """Geodesic distance in metres between two (lat, lon) points."""
    return WGS84.inv(a[1], a[0], b[1], b[0])[2]


def bearing_deg(a: tuple[float, float], b: tuple[float, float]) -> float:
    """Initial azimuth from ``a`` to ``b``, degrees clockwise from north."""
    return WGS84.inv(a[1], a[0], b[1], b[0])[0]


def inside(ring: tuple[tuple[float, float], ...], point: tuple[float, float]) -> bool:
    """Whether a (lat, lon) point lies inside a small (lat, lon) ring (even-odd rule).

    Planar is exact enough for a field of a few hundred metres, and keeps this
    check dependency-free for the request collection's expectations.
    """
    lat, lon = point
    result = False
    for (lat1, lon1), (lat2, lon2) in itertools.pairwise(ring):
        if (lat1 > lat) != (lat2 > lat):
            crossing = lon1 + (lat - lat1) * (lon2 - lon1) / (lat2 - lat1)
            if lon < crossing:
                result = not result
    return result


def sensors_within(point: tuple[float, float], max_distance_m: float) -> list[str]:
    """Ids of the sensors no further than ``max_distance_m`` from ``point``."""
    return [sensor_id for sensor_id, where, _ in SENSORS if distance_m(point, where) <= max_distance_m]


def sensors_inside(ring: tuple[tuple[float, float], ...]) -> list[str]:
    """Ids of the sensors inside a (lat, lon) ring."""
    return [sensor_id for sensor_id, where, _ in SENSORS if inside(ring, where)]
