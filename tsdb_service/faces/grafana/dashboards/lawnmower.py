"""Bosch lawnmower: current values, then the history of states and perimeter detections."""

from __future__ import annotations

from grafana_foundation_sdk.models import common

from tsdb_service.faces.grafana.dashboards import kit
from tsdb_service.faces.grafana.dashboards.kit import Query, attrs
from tsdb_service.usecases import sites
from tsdb_service.usecases.enums import LAWNMOWER_NAVIGATION_STATE, LAWNMOWER_NAVIGATION_SUBSTATE

UID = "tsdb-lawnmower"
DS = kit.DATASOURCES["lawnmower"]
MOWER = sites.LAWNMOWER_ID

SPEED = attrs(linear="odom(twist.twist.linear.x)", angular="odom(twist.twist.angular.z)")
STATE_COLORS = {
    "docked": "blue",
    "leaving dock": "purple",
    "mowing": "green",
    "returning to dock": "yellow",
    "docking": "light-blue",
    "remote control": "orange",
    "error": "red",
}
SUBSTATE_COLORS = {
    "idle": "text",
    "charging": "blue",
    "driving straight": "green",
    "turning": "light-green",
    "perimeter detected": "red",
    "avoiding obstacle": "orange",
    "following border wire": "yellow",
    "manual driving": "purple",
}


def latest(field: str, path: str, kind: str = "number") -> Query:
    return Query(DS, "latest", [(field, kind)], time=False, id=MOWER, attrs=attrs(**{field: path}))


def build():
    ids = kit.Ids()
    state_map = kit.value_mappings(LAWNMOWER_NAVIGATION_STATE, STATE_COLORS)
    substate_map = kit.value_mappings(LAWNMOWER_NAVIGATION_SUBSTATE, SUBSTATE_COLORS)
    perimeter_map = kit.bool_mappings("wire detected", "inside")
    dash = kit.dashboard(
        UID,
        "Bosch lawnmower",
        "A robotic lawnmower reported by the ROS 2 IoT Agent (entity ROS2System:Lawnmower01, tenant lawnmower).",
        ["lawnmower", "bosch"],
        "now-30m",
        "10s",
    )
    dash = dash.with_row(kit.row(ids, "Current values"))
    speed_steps = kit.thresholds("blue", (-0.05, "green"), (0.45, "orange"))
    dash = dash.with_panel(
        kit.gauge_panel(
            ids,
            DS,
            "Linear speed",
            latest("linear", "odom(twist.twist.linear.x)"),
            "linear",
            unit="velocityms",
            low=-0.5,
            high=0.5,
            thresholds_=speed_steps,
            description="odom → twist.twist.linear.x (nav_msgs/Odometry)",
        )
    )
    dash = dash.with_panel(
        kit.gauge_panel(
            ids,
            DS,
            "Angular speed",
            latest("angular", "odom(twist.twist.angular.z)"),
            "angular",
            unit="rotrads",
            low=-1.0,
            high=1.0,
            thresholds_=kit.thresholds("green", (0.7, "orange")),
            description="odom → twist.twist.angular.z (yaw rate)",
        )
    )
    dash = dash.with_panel(
        kit.stat_panel(
            ids,
            DS,
            "Closest obstacle",
            latest("obstacle", "obstacleDistance(range)"),
            "obstacle",
            unit="lengthm",
            decimals=2,
            thresholds_=kit.thresholds("red", (0.35, "orange"), (1.0, "green")),
            description="obstacleDistance → range (sensor_msgs/Range, ultrasound)",
        )
    )
    dash = dash.with_panel(
        kit.stat_panel(
            ids,
            DS,
            "Left perimeter",
            latest("left", "perimeterLeft(data)", "boolean"),
            "left",
            w=3,
            mappings=perimeter_map,
        )
    )
    dash = dash.with_panel(
        kit.stat_panel(
            ids,
            DS,
            "Right perimeter",
            latest("right", "perimeterRight(data)", "boolean"),
            "right",
            w=3,
            mappings=perimeter_map,
        )
    )
    dash = dash.with_panel(
        kit.stat_panel(
            ids,
            DS,
            "Navigation state",
            latest("state", "navigationState(data)"),
            "state",
            w=3,
            mappings=state_map,
        )
    )
    dash = dash.with_panel(
        kit.stat_panel(
            ids,
            DS,
            "Navigation sub-state",
            latest("substate", "navigationSubState(data)"),
            "substate",
            w=3,
            mappings=substate_map,
        )
    )

    dash = dash.with_row(kit.row(ids, "History"))
    for title, field, path, mappings in (
        ("Navigation state", "state", "navigationState(data)", state_map),
        ("Navigation sub-state", "substate", "navigationSubState(data)", substate_map),
    ):
        states = Query(
            DS,
            "states",
            [("time", "timestamp"), (field, "number")],
            id=MOWER,
            attrs=attrs(**{field: path}),
            max_points=2000,
        )
        dash = dash.with_panel(kit.state_timeline_panel(ids, DS, title, states, mappings))
    perimeter = Query(
        DS,
        "states",
        [("time", "timestamp"), ("left", "boolean"), ("right", "boolean")],
        id=MOWER,
        attrs=attrs(left="perimeterLeft(data)", right="perimeterRight(data)"),
        max_points=2000,
    )
    dash = dash.with_panel(
        kit.state_timeline_panel(
            ids,
            DS,
            "Perimeter detections (left and right coil)",
            perimeter,
            perimeter_map,
            h=6,
        )
    )
    speeds = Query(
        DS,
        "series",
        [("time", "timestamp"), ("linear", "number"), ("angular", "number")],
        interval=True,
        max_points=1000,
        id=MOWER,
        attrs=SPEED,
    )
    dash = dash.with_panel(
        kit.timeseries_panel(
            ids,
            DS,
            "Speed",
            speeds,
            max_points=1000,
            description="linear (m/s) and angular (rad/s) speed from odom, averaged per interval",
        )
    )
    obstacle = Query(
        DS,
        "series",
        [("time", "timestamp"), ("obstacle", "number")],
        interval=True,
        max_points=1000,
        id=MOWER,
        attrs=attrs(obstacle="obstacleDistance(range)"),
    )
    dash = dash.with_panel(
        kit.timeseries_panel(
            ids,
            DS,
            "Distance to the closest obstacle",
            obstacle,
            unit="lengthm",
            max_points=1000,
            thresholds_=kit.thresholds("red", (0.35, "transparent")),
            threshold_style=common.GraphThresholdsStyleMode.LINE_AND_AREA,
        )
    )
    events = Query(
        DS,
        "events",
        [("time", "timestamp"), ("timeEnd", "timestamp"), ("title", "string"), ("text", "string"), ("tags", "string")],
        id=MOWER,
        attrs=attrs(left="perimeterLeft(data)", right="perimeterRight(data)"),
        text="Perimeter wire detected",
    )
    dash = dash.annotation(kit.annotation("Perimeter detections", DS, events, "red"))
    return dash
