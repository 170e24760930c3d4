"""eProsima drone: where the drone and the 8 remote sensors are, where the drone flew, what the sensors measure."""

from __future__ import annotations

from grafana_foundation_sdk.builders import barchart, geomap, table
from grafana_foundation_sdk.builders import common as cb
from grafana_foundation_sdk.models import common
from grafana_foundation_sdk.models import dashboard as dm
from grafana_foundation_sdk.models import geomap as gm

from tsdb_service.faces.grafana.dashboards import kit
from tsdb_service.faces.grafana.dashboards.kit import Query, attrs
from tsdb_service.usecases import sites
from tsdb_service.usecases.enums import DRONE_MISSION_STATE

UID = "tsdb-drone"
DS = kit.DATASOURCES["drone"]
DRONE = sites.DRONE_ID
CENTRE = (40.6065, -3.6875)  # between home and the sensor field
MISSION_COLORS = {
    "landed at home": "text",
    "taking off": "purple",
    "flying to sensor": "blue",
    "reading sensor": "green",
    "returning home": "light-blue",
    "landing": "purple",
}
TYPE_COLORS: list[dm.ValueMapping] = [
    dm.ValueMap(
        options={
            "ROS2System": dm.ValueMappingResult(text="drone", color="red", index=0),
            sites.SENSOR_TYPE: dm.ValueMappingResult(text="remote sensor", color="green", index=1),
        }
    )
]
COORDS = cb.FrameGeometrySource().mode(common.FrameGeometrySourceMode.COORDS).latitude("lat").longitude("lon")


def _view(zoom: int) -> geomap.MapViewConfig:
    view = geomap.MapViewConfig().id("coords")
    # The SDK types lat/lon as int (from Grafana's panel schema); the map takes degrees, fractions included.
    view = view.lat(CENTRE[0]).lon(CENTRE[1])  # type: ignore[arg-type]
    return view.zoom(zoom).all_layers(True)


def _controls() -> geomap.ControlsOptions:
    return (
        geomap.ControlsOptions()
        .show_zoom(True)
        .mouse_wheel_zoom(True)
        .show_attribution(True)
        .show_scale(True)
        .show_debug(False)
        .show_measure(False)
    )


def build():
    ids = kit.Ids()
    mission_map = kit.value_mappings(DRONE_MISSION_STATE, MISSION_COLORS)
    dash = kit.dashboard(
        UID,
        "eProsima drone",
        "A drone flying missions from home to 8 remote sensors and reading their temperature and humidity "
        "(tenant drone): positions are GPS geo:json Points.",
        ["drone", "eprosima"],
        "now-6h",
        "30s",
    )
    dash = dash.with_row(kit.row(ids, "Map"))
    where = Query(
        DS,
        "positions",
        [
            ("entity", "string"),
            ("name", "string"),
            ("type", "string"),
            ("lat", "number"),
            ("lon", "number"),
            ("temperature", "number"),
            ("humidity", "number"),
        ],
        time=False,
        latest="true",
        attrs=attrs(temperature="temperature", humidity="humidity"),
    )
    markers = (
        cb.MapLayerOptions()
        .type("markers")
        .name("Drone and sensors")
        .location(COORDS)
        .tooltip(True)
        .config(
            {
                "showLegend": True,
                "style": {
                    "size": {"fixed": 9, "min": 4, "max": 15},
                    "color": {"field": "type", "fixed": "dark-green"},
                    "opacity": 0.9,
                    "symbol": {"fixed": "img/icons/marker/circle.svg", "mode": "fixed"},
                    "symbolAlign": {"horizontal": "center", "vertical": "center"},
                    "text": {"field": "name", "fixed": "", "mode": "field"},
                    "textConfig": {
                        "fontSize": 11,
                        "offsetX": 0,
                        "offsetY": -14,
                        "textAlign": "center",
                        "textBaseline": "bottom",
                    },
                },
            }
        )
    )
    positions_map = (
        geomap.Panel()
        .id(ids())
        .title("Drone and remote sensors (hover for the latest readings)")
        .span(12)
        .height(13)
        .datasource(DS.ref)
        .with_target(where)
        .view(_view(15))
        .controls(_controls())
        .basemap(cb.MapLayerOptions().type("osm-standard").name("OpenStreetMap").config({}))
        .layers([markers])
        .tooltip(geomap.TooltipOptions().mode(gm.TooltipMode.DETAILS))
        .mappings(TYPE_COLORS)
        .description(
            "Each entity's latest position; sensors carry their latest temperature (°C) and "
            "humidity (%). Red: the drone; green: the remote sensors."
        )
    )
    dash = dash.with_panel(positions_map)
    track = Query(
        DS, "positions", [("time", "timestamp"), ("lat", "number"), ("lon", "number")], id=DRONE, max_points=5000
    )
    heat = (
        cb.MapLayerOptions()
        .type("heatmap")
        .name("Drone positions")
        .location(COORDS)
        .tooltip(False)
        .config({"blur": 15, "radius": 6, "weight": {"fixed": 1, "min": 0, "max": 1}})
    )
    heat_map = (
        geomap.Panel()
        .id(ids())
        .title("Where the drone flew (heatmap of its positions)")
        .span(12)
        .height(13)
        .datasource(DS.ref)
        .with_target(track)
        .max_data_points(5000)
        .view(_view(15))
        .controls(_controls())
        .basemap(cb.MapLayerOptions().type("carto").name("Dark").config({"theme": "dark", "showLabels": True}))
        .layers([heat])
        .tooltip(geomap.TooltipOptions().mode(gm.TooltipMode.NONE))
    )
    dash = dash.with_panel(heat_map)

    dash = dash.with_row(kit.row(ids, "Remote sensors"))
    averages = Query(
        DS,
        "aggregate",
        [("name", "string"), ("temperature", "number"), ("humidity", "number")],
        type=sites.SENSOR_TYPE,
        method="avg",
        attrs=attrs(temperature="temperature", humidity="humidity"),
    )
    bars = (
        barchart.Panel()
        .id(ids())
        .title("Average measures per sensor")
        .span(12)
        .height(9)
        .datasource(DS.ref)
        .with_target(averages)
        .x_field("name")
        .show_value(common.VisibilityMode.AUTO)
        .bar_width(0.8)
        .group_width(0.7)
        .fill_opacity(80)
        .gradient_mode(common.GraphGradientMode.NONE)
        .x_tick_label_rotation(0)
        .x_tick_label_spacing(0)
        .orientation(common.VizOrientation.AUTO)
        .stacking(common.StackingMode.NONE)
        .full_highlight(False)
        .decimals(1)
        .legend(
            cb.VizLegendOptions()
            .show_legend(True)
            .display_mode(common.LegendDisplayMode.LIST)
            .placement(common.LegendPlacement.BOTTOM)
            .calcs([])
        )
        .tooltip(cb.VizTooltipOptions().mode(common.TooltipDisplayMode.MULTI).sort(common.SortOrder.NONE))
        .description("Mean temperature (°C) and humidity (%) of each sensor's readings in the time range")
    )
    dash = dash.with_panel(bars)
    readings = Query(
        DS,
        "latest",
        [
            ("name", "string"),
            ("time", "timestamp"),
            ("temperature", "number"),
            ("humidity", "number"),
            ("priority", "number"),
        ],
        time=False,
        type=sites.SENSOR_TYPE,
        attrs=attrs(temperature="temperature", humidity="humidity", priority="priority"),
    )
    latest_table = (
        table.Panel()
        .id(ids())
        .title("Latest sensor readings")
        .span(12)
        .height(9)
        .datasource(DS.ref)
        .with_target(readings)
        .show_header(True)
        .cell_height(common.TableCellHeight.SM)
        .sort_by([cb.TableSortByFieldState().display_name("name").desc(False)])
        .description("Temperature in °C, humidity in %, mission priority as a share of the missions")
    )
    dash = dash.with_panel(latest_table)

    dash = dash.with_row(kit.row(ids, "Flights"))
    missions = Query(
        DS,
        "states",
        [("time", "timestamp"), ("mission", "number")],
        id=DRONE,
        max_points=2000,
        attrs=attrs(mission="missionState(data)"),
    )
    dash = dash.with_panel(kit.state_timeline_panel(ids, DS, "Mission state", missions, mission_map))
    for title, field, path, unit in (
        ("Altitude above home", "altitude", "altitude(data)", "lengthm"),
        ("Battery", "battery", "battery(data)", "percent"),
    ):
        flight = Query(
            DS,
            "series",
            [("time", "timestamp"), (field, "number")],
            interval=True,
            max_points=1000,
            id=DRONE,
            attrs=attrs(**{field: path}),
        )
        dash = dash.with_panel(kit.timeseries_panel(ids, DS, title, flight, unit=unit, max_points=1000))
    reading = str(next(code for code, name in DRONE_MISSION_STATE.items() if name == "reading sensor"))
    readings = Query(
        DS,
        "events",
        [("time", "timestamp"), ("timeEnd", "timestamp"), ("title", "string"), ("text", "string"), ("tags", "string")],
        id=DRONE,
        attrs=attrs(reading="missionState(data)"),
        equals=reading,
        text="The drone hovers over a sensor and reads it",
    )
    dash = dash.annotation(kit.annotation("Sensor readings", DS, readings, "green"))
    return dash
