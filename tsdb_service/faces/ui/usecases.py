"""The use cases as the explorer page needs them, from the demo's definitions."""

from __future__ import annotations

from tsdb_service.usecases import enums, sites
from tsdb_service.usecases.registry import SIMULATORS


def _tenancy(tenancy: sites.Tenancy) -> dict:
    return {"service": tenancy.service, "servicePath": tenancy.service_path}


def _enums(name: str) -> dict[str, dict[str, str]]:
    """JSON objects have string keys: ``{"navigationState": {"0": "docked", ...}}``."""
    return {attr: {str(k): v for k, v in table.items()} for attr, table in enums.ENUMERATIONS[name].items()}


def _garden() -> list[list[float]]:
    """The garden's border wire as a closed (lat, lon) ring."""
    corners = (
        (0, 0),
        (sites.GARDEN_WIDTH_M, 0),
        (sites.GARDEN_WIDTH_M, sites.GARDEN_DEPTH_M),
        (0, sites.GARDEN_DEPTH_M),
        (0, 0),
    )
    return [list(sites.offset(sites.GARDEN_ORIGIN, east, north)) for east, north in corners]


def describe() -> dict:
    return {
        "lawnmower": {
            "title": SIMULATORS["lawnmower"].title,
            **_tenancy(sites.LAWNMOWER),
            "entity": sites.LAWNMOWER_ID,
            "enums": _enums("lawnmower"),
            "garden": _garden(),
        },
        "warehouse": {
            "title": SIMULATORS["warehouse"].title,
            **_tenancy(sites.WAREHOUSE),
            "entity": sites.WAREHOUSE_ID,
            "robot": sites.WAREHOUSE_ROBOT_ID,
            "doorOpenDistanceM": sites.DOOR_OPEN_DISTANCE_M,
            "enums": _enums("warehouse"),
        },
        "drone": {
            "title": SIMULATORS["drone"].title,
            **_tenancy(sites.DRONE),
            "entity": sites.DRONE_ID,
            "sensorType": sites.SENSOR_TYPE,
            "sensors": [
                {"id": sid, "lat": lat, "lon": lon, "priority": priority} for sid, (lat, lon), priority in sites.SENSORS
            ],
            "home": list(sites.DRONE_HOME),
            "field": [list(point) for point in sites.SENSOR_FIELD],
            "enums": _enums("drone"),
        },
    }
