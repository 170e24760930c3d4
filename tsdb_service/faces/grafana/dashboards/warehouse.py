"""PIAP smart warehouse: environment, the automated door and its laser gate, and their history."""

from __future__ import annotations

from grafana_foundation_sdk.builders import barchart
from grafana_foundation_sdk.builders import common as cb
from grafana_foundation_sdk.builders import dashboard as db
from grafana_foundation_sdk.models import common
from grafana_foundation_sdk.models import dashboard as dm

from tsdb_service.faces.grafana.dashboards import kit
from tsdb_service.faces.grafana.dashboards.kit import Query, attrs
from tsdb_service.usecases import sites
from tsdb_service.usecases.enums import DOOR_COMMAND, DOOR_STATE, WARNING_LIGHT_COMMAND, WARNING_LIGHT_STATE

UID = "tsdb-warehouse"
DS = kit.DATASOURCES["warehouse"]
SITE = sites.WAREHOUSE_ID
OPEN_AT = sites.DOOR_OPEN_DISTANCE_M  # the door controller's 60 cm

DOOR_COLORS = {"closed": "green", "open": "red", "in motion": "yellow"}
COMMAND_COLORS = {"idle": "text", "open": "orange", "close": "blue", "stop": "red"}
LIGHT_COLORS = {"off": "text", "on": "orange"}
TEMPERATURE = kit.thresholds("blue", (16, "green"), (24, "orange"), (28, "red"))
HUMIDITY = kit.thresholds("orange", (30, "green"), (60, "orange"), (70, "red"))
LASER = kit.thresholds("red", (OPEN_AT, "green"))
# The light and its command share one state-timeline panel, so one mapping.
assert WARNING_LIGHT_COMMAND == WARNING_LIGHT_STATE, "the warning light's state and command codes differ"


def latest(field: str, path: str) -> Query:
    return Query(DS, "latest", [(field, "number")], time=False, id=SITE, attrs=attrs(**{field: path}))


def build():
    ids = kit.Ids()
    door_map = kit.value_mappings(DOOR_STATE, DOOR_COLORS)
    command_map = kit.value_mappings(DOOR_COMMAND, COMMAND_COLORS)
    light_map = kit.value_mappings(WARNING_LIGHT_STATE, LIGHT_COLORS)
    dash = kit.dashboard(
        UID,
        "PIAP smart warehouse",
        "A robot passing an automated door (entity ROS2System:PiapWarehouse01, tenant warehouse): the door opens "
        f"when the laser gate measures the robot closer than {OPEN_AT * 100:.0f} cm.",
        ["warehouse", "piap"],
        "now-15m",
        "5s",
    )
    dash = dash.with_row(kit.row(ids, "Now"))
    dash = dash.with_panel(
        kit.stat_panel(
            ids,
            DS,
            "Temperature",
            latest("temperature", "temperature(data)"),
            "temperature",
            unit="celsius",
            decimals=1,
            thresholds_=TEMPERATURE,
            description="temperature → data (std_msgs/Float32)",
        )
    )
    dash = dash.with_panel(
        kit.gauge_panel(
            ids,
            DS,
            "Humidity",
            latest("humidity", "humidity(data)"),
            "humidity",
            unit="percent",
            low=0,
            high=100,
            thresholds_=HUMIDITY,
            description="humidity → data (std_msgs/Float32)",
        )
    )
    dash = dash.with_panel(
        kit.stat_panel(
            ids,
            DS,
            "Door",
            latest("door", "doorState(data)"),
            "door",
            mappings=door_map,
        )
    )
    dash = dash.with_panel(
        kit.stat_panel(
            ids,
            DS,
            "Door command",
            latest("command", "doorCommand(data)"),
            "command",
            mappings=command_map,
        )
    )
    dash = dash.with_panel(
        kit.stat_panel(
            ids,
            DS,
            "Warning light",
            latest("light", "warningLight(data)"),
            "light",
            mappings=light_map,
        )
    )
    dash = dash.with_panel(
        kit.stat_panel(
            ids,
            DS,
            "Robot distance to the door",
            latest("distance", "laserDistance(range)"),
            "distance",
            unit="lengthm",
            decimals=2,
            thresholds_=LASER,
        )
    )
    laser = Query(
        DS,
        "series",
        [("time", "timestamp"), ("distance", "number")],
        interval=True,
        max_points=60,
        id=SITE,
        attrs=attrs(distance="laserDistance(range)"),
    )
    bars = (
        barchart.Panel()
        .id(ids())
        .title(f"Laser distance, last 5 minutes (the door opens under {OPEN_AT:g} m)")
        .span(24)
        .height(8)
        .datasource(DS.ref)
        .with_target(laser)
        .time_from("5m")
        .max_data_points(60)
        .x_field("time")
        .show_value(common.VisibilityMode.NEVER)
        .bar_width(0.9)
        .group_width(0.7)
        .fill_opacity(80)
        .gradient_mode(common.GraphGradientMode.NONE)
        .x_tick_label_rotation(0)
        .x_tick_label_spacing(100)
        .orientation(common.VizOrientation.AUTO)
        .stacking(common.StackingMode.NONE)
        .full_highlight(False)
        .legend(
            cb.VizLegendOptions()
            .show_legend(False)
            .display_mode(common.LegendDisplayMode.LIST)
            .placement(common.LegendPlacement.BOTTOM)
            .calcs([])
        )
        .tooltip(cb.VizTooltipOptions().mode(common.TooltipDisplayMode.SINGLE).sort(common.SortOrder.NONE))
        .unit("lengthm")
        .min(0)
        .thresholds(LASER)
        .color_scheme(db.FieldColor().mode(dm.FieldColorModeId.THRESHOLDS))
        .thresholds_style(cb.GraphThresholdsStyleConfig().mode(common.GraphThresholdsStyleMode.DASHED))
        .description(
            "laserDistance → range (sensor_msgs/Range): the robot's distance measured by the door's "
            "laser gate, averaged per bar; the dashed line is the 60 cm opening threshold"
        )
    )
    dash = dash.with_panel(bars)

    dash = dash.with_row(kit.row(ids, "History"))
    for title, field, path, unit, steps in (
        ("Temperature", "temperature", "temperature(data)", "celsius", TEMPERATURE),
        ("Humidity", "humidity", "humidity(data)", "percent", HUMIDITY),
    ):
        env = Query(
            DS,
            "series",
            [("time", "timestamp"), (field, "number")],
            interval=True,
            max_points=1000,
            id=SITE,
            attrs=attrs(**{field: path}),
        )
        dash = dash.with_panel(
            kit.timeseries_panel(
                ids,
                DS,
                title,
                env,
                w=8,
                unit=unit,
                max_points=1000,
                thresholds_=steps,
                threshold_style=common.GraphThresholdsStyleMode.AREA,
            ).color_scheme(db.FieldColor().mode(dm.FieldColorModeId.THRESHOLDS))
        )
    distance = Query(
        DS,
        "series",
        [("time", "timestamp"), ("distance", "number")],
        interval=True,
        max_points=1000,
        id=SITE,
        attrs=attrs(distance="laserDistance(range)"),
    )
    dash = dash.with_panel(
        kit.timeseries_panel(
            ids,
            DS,
            "Laser distance",
            distance,
            w=8,
            unit="lengthm",
            max_points=1000,
            thresholds_=LASER,
            threshold_style=common.GraphThresholdsStyleMode.DASHED_AND_AREA,
        )
    )
    for title, fields, mappings in (
        ("Door state", {"door": "doorState(data)"}, door_map),
        ("Door command", {"command": "doorCommand(data)"}, command_map),
        (
            "Warning light and its command",
            {"light": "warningLight(data)", "light_command": "warningLightCommand(data)"},
            light_map,
        ),
    ):
        states = Query(
            DS,
            "states",
            [("time", "timestamp"), *((f, "number") for f in fields)],
            id=SITE,
            max_points=2000,
            attrs=attrs(**fields),
        )
        dash = dash.with_panel(
            kit.state_timeline_panel(ids, DS, title, states, mappings, h=5 if len(fields) == 1 else 6)
        )
    openings = Query(
        DS,
        "events",
        [("time", "timestamp"), ("timeEnd", "timestamp"), ("title", "string"), ("text", "string"), ("tags", "string")],
        id=SITE,
        attrs=attrs(door_open="doorCommand(data)"),
        equals="1",
        text="The door controller opens the door",
    )
    dash = dash.annotation(kit.annotation("Door openings", DS, openings, "orange"))
    return dash
