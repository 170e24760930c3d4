"""eProsima drone through the NGSI-LD temporal API: the same data as
``drone.py`` (notified over NGSIv2, tenant ``drone``), read the way an
NGSI-LD client reads history: ``/ngsi-ld/v1/temporal/entities``.

Every target is an Infinity JSON query with the *backend* parser and only
simple gjson paths (dotted keys and array indexes, no modifiers, no
JSONata): a root selector picks an array out of the temporal
representation, columns pick each row's members. With
``options=temporalValues`` an attribute is ``{"values": [[value, time],
...]}``, so ``<attr>.values`` is the root and ``1`` / ``0.data`` the
columns; ``format=aggregatedValues`` gives ``{"avg": [[value, start, end],
...]}`` per attribute; a query over a type returns an array of entities,
one row each.
"""

from __future__ import annotations

from grafana_foundation_sdk.builders import barchart, geomap, table
from grafana_foundation_sdk.builders import common as cb
from grafana_foundation_sdk.cog import builder as cogbuilder
from grafana_foundation_sdk.cog import variants as cogvariants
from grafana_foundation_sdk.models import common
from grafana_foundation_sdk.models import geomap as gm

from tsdb_service.faces.grafana.dashboards import drone, kit
from tsdb_service.usecases import sites
from tsdb_service.usecases.enums import DRONE_MISSION_STATE

UID = "tsdb-drone-ld"
DS = kit.DATASOURCES["drone"]  # the tenant travels as Fiware-Service, which NGSI-LD reads accept too
API = "/ngsi-ld/v1/temporal/entities"
DRONE = sites.DRONE_ID
BUSIEST_SENSOR = max(sites.SENSORS, key=lambda s: s[2])[0]  # the most visited: highest mission priority
FROM, TO = "${__from:date:iso}", "${__to:date:iso}"
LAST_N = 2000  # instances per attribute: the newest, as Grafana draws a window's end first


class LdQuery(cogbuilder.Builder[cogvariants.Dataquery]):
    """``LdQuery(path, root, [(selector, name, type)], **params)``: a GET of
    the temporal API; the window is the dashboard's time range."""

    def __init__(
        self,
        path: str,
        root: str,
        columns: list[tuple[str, str, str]],
        *,
        ref_id: str = "A",
        window: bool = True,
        **params: str,
    ) -> None:
        pairs = list(params.items())
        if window:
            pairs += [("timerel", "between"), ("timeAt", FROM), ("endTimeAt", TO)]
        self._query = kit.InfinityQuery(
            refId=ref_id,
            datasource=DS.ref.to_json(),
            type="json",
            source="url",
            parser="backend",
            format="table",
            url=path,
            url_options={
                "method": "GET",
                "data": "",
                "params": [{"key": key, "value": value} for key, value in pairs],
                "headers": [],
            },
            root_selector=root,
            columns=[{"selector": selector, "text": name, "type": kind} for selector, name, kind in columns],
            filters=[],
            computed_columns=[],
        )

    def build(self) -> kit.InfinityQuery:
        return self._query


def values(entity: str, attr: str, name: str, member: str = "0.data", **params: str) -> LdQuery:
    """One attribute of one entity as (time, value) rows (``options=temporalValues``)."""
    return LdQuery(
        f"{API}/{entity}",
        f"{attr}.values",
        [("1", "time", "timestamp"), (member, name, "number")],
        attrs=attr,
        options="temporalValues",
        lastN=str(LAST_N),
        window=True,
        **params,
    )


def aggregate(entity: str, attr: str, method: str, ref_id: str) -> LdQuery:
    """``method`` of one attribute per 15 minutes, as (period start, value) rows."""
    return LdQuery(
        f"{API}/{entity}",
        f"{attr}.{method}",
        [("1", "time", "timestamp"), ("0", method, "number")],
        ref_id=ref_id,
        attrs=attr,
        format="aggregatedValues",
        aggrMethods=method,
        aggrPeriodDuration="PT15M",
    )


def build():
    ids = kit.Ids()
    dash = kit.dashboard(
        UID,
        "eProsima drone (NGSI-LD temporal API)",
        "The drone use case read through the NGSI-LD temporal API (/ngsi-ld/v1/temporal/entities): "
        "temporalValues for the flight, aggregatedValues for the sensors (tenant drone).",
        ["drone", "eprosima", "ngsi-ld"],
        "now-6h",
        "30s",
    )
    dash = dash.with_row(kit.row(ids, "Flight (options=temporalValues)"))
    for title, attr, unit in (("Altitude above home", "altitude", "lengthm"), ("Battery", "battery", "percent")):
        dash = dash.with_panel(kit.timeseries_panel(ids, DS, title, values(DRONE, attr, attr), unit=unit))
    mission_map = kit.value_mappings(DRONE_MISSION_STATE, drone.MISSION_COLORS)
    dash = dash.with_panel(
        kit.state_timeline_panel(
            ids,
            DS,
            "Mission state",
            values(DRONE, "missionState", "mission"),
            mission_map,
            description="missionState.values of the drone: [value, observedAt] pairs",
        )
    )
    track = LdQuery(
        f"{API}/{DRONE}",
        "location.values",
        [("1", "time", "timestamp"), ("0.coordinates.1", "lat", "number"), ("0.coordinates.0", "lon", "number")],
        attrs="location",
        options="temporalValues",
        lastN=str(LAST_N),
    )
    heat = (
        cb.MapLayerOptions()
        .type("heatmap")
        .name("Drone positions")
        .location(drone.COORDS)
        .tooltip(False)
        .config({"blur": 15, "radius": 6, "weight": {"fixed": 1, "min": 0, "max": 1}})
    )
    dash = dash.with_panel(
        geomap.Panel()
        .id(ids())
        .title("Where the drone flew (location.values)")
        .span(24)
        .height(12)
        .datasource(DS.ref)
        .with_target(track)
        .view(drone._view(15))
        .controls(drone._controls())
        .basemap(cb.MapLayerOptions().type("carto").name("Dark").config({"theme": "dark", "showLabels": True}))
        .layers([heat])
        .tooltip(geomap.TooltipOptions().mode(gm.TooltipMode.NONE))
    )

    dash = dash.with_row(kit.row(ids, "Remote sensors (format=aggregatedValues)"))
    averages = LdQuery(
        API,
        "",
        [
            ("id", "id", "string"),
            ("temperature.avg.0.0", "temperature", "number"),
            ("humidity.avg.0.0", "humidity", "number"),
        ],
        type=sites.SENSOR_TYPE,
        attrs="temperature,humidity",
        format="aggregatedValues",
        aggrMethods="avg",
        aggrPeriodDuration="PT0S",
        limit="100",
    )
    dash = dash.with_panel(
        barchart.Panel()
        .id(ids())
        .title("Average measures per sensor (one period: PT0S)")
        .span(12)
        .height(9)
        .datasource(DS.ref)
        .with_target(averages)
        .x_field("id")
        .show_value(common.VisibilityMode.AUTO)
        .bar_width(0.8)
        .group_width(0.7)
        .fill_opacity(80)
        .gradient_mode(common.GraphGradientMode.NONE)
        .x_tick_label_rotation(-30)
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
        .description("temperature.avg and humidity.avg of each RemoteSensor over the time range")
    )
    spread = (
        kit.timeseries_panel(
            ids,
            DS,
            "Busiest sensor's temperature per 15 minutes (min / avg / max)",
            aggregate(BUSIEST_SENSOR, "temperature", "min", "A"),
            h=9,
            unit="celsius",
            draw_style=common.GraphDrawStyle.POINTS,
            description=f"aggregatedValues of {BUSIEST_SENSOR}: one query per method",
        )
        .with_target(aggregate(BUSIEST_SENSOR, "temperature", "avg", "B"))
        .with_target(aggregate(BUSIEST_SENSOR, "temperature", "max", "C"))
    )
    dash = dash.with_panel(spread)
    latest = LdQuery(
        API,
        "",
        [
            ("id", "id", "string"),
            ("temperature.values.0.1", "time", "timestamp"),
            ("temperature.values.0.0", "temperature", "number"),
            ("humidity.values.0.0", "humidity", "number"),
        ],
        window=False,
        type=sites.SENSOR_TYPE,
        attrs="temperature,humidity",
        options="temporalValues",
        lastN="1",
        limit="100",
    )
    dash = dash.with_panel(
        table.Panel()
        .id(ids())
        .title("Latest sensor readings (lastN=1)")
        .span(24)
        .height(8)
        .datasource(DS.ref)
        .with_target(latest)
        .show_header(True)
        .cell_height(common.TableCellHeight.SM)
        .sort_by([cb.TableSortByFieldState().display_name("id").desc(False)])
        .description("Each sensor's newest temperature (°C) and humidity (%), whatever the time range")
    )
    return dash
