"""What every use-case dashboard is made of: datasources, Infinity queries,
value mappings, thresholds and the panel shapes we use, on top of
grafana-foundation-sdk 0.0.21.

The SDK has no model for Infinity queries, so ``InfinityQuery`` is one: a
``Dataquery`` variant registered for ``yesoreyeram-infinity-datasource``, so
``Dashboard.from_json`` decodes our targets into it (and a misspelt key is
lost in a round trip, which the tests catch).
"""

from __future__ import annotations

import typing
from collections.abc import Sequence
from dataclasses import dataclass

from grafana_foundation_sdk.builders import common as cb
from grafana_foundation_sdk.builders import dashboard as db
from grafana_foundation_sdk.builders import gauge, stat, statetimeline, timeseries
from grafana_foundation_sdk.cog import builder as cogbuilder
from grafana_foundation_sdk.cog import runtime as cogruntime
from grafana_foundation_sdk.cog import variants as cogvariants
from grafana_foundation_sdk.models import common
from grafana_foundation_sdk.models import dashboard as dm

from tsdb_service.usecases import sites

INFINITY = "yesoreyeram-infinity-datasource"
SERVICE_URL = "http://tsdb-service:8668"  # the service's name in a compose file
API = "/grafana/infinity"


@dataclass(frozen=True)
class Datasource:
    """One Infinity datasource per use case: the tenant travels as custom headers."""

    uid: str
    name: str
    tenancy: sites.Tenancy

    @property
    def ref(self) -> common.DataSourceRef:
        return common.DataSourceRef(type_val=INFINITY, uid=self.uid)


DATASOURCES: dict[str, Datasource] = {
    "lawnmower": Datasource("tsdb-lawnmower", "tsdb-service lawnmower", sites.LAWNMOWER),
    "warehouse": Datasource("tsdb-warehouse", "tsdb-service warehouse", sites.WAREHOUSE),
    "drone": Datasource("tsdb-drone", "tsdb-service drone", sites.DRONE),
}


# --- the Infinity query model -----------------------------------------------------------------

_QUERY_KEYS = (
    "refId",
    "datasource",
    "type",
    "source",
    "parser",
    "format",
    "url",
    "url_options",
    "root_selector",
    "columns",
    "filters",
    "computed_columns",
    "hide",
)
_URL_OPTION_KEYS = ("method", "data", "params", "headers")
_COLUMN_KEYS = ("selector", "text", "type")


class InfinityQuery(cogvariants.Dataquery):
    """An Infinity target: a GET of flat JSON rows, parsed by the backend parser."""

    def __init__(self, **fields: typing.Any) -> None:
        self.fields = fields

    def to_json(self) -> dict[str, object]:
        return dict(self.fields)

    @classmethod
    def from_json(cls, data: dict[str, typing.Any]) -> InfinityQuery:
        fields = {key: data[key] for key in _QUERY_KEYS if key in data}
        options = fields.get("url_options")
        if isinstance(options, dict):
            fields["url_options"] = {key: options[key] for key in _URL_OPTION_KEYS if key in options}
        if isinstance(fields.get("columns"), list):
            fields["columns"] = [
                {key: col[key] for key in _COLUMN_KEYS if key in col}
                for col in fields["columns"]
                if isinstance(col, dict)
            ]
        return cls(**fields)


def register() -> None:
    """Teach the SDK's decoder the panel types and our Infinity targets (idempotent)."""
    from grafana_foundation_sdk.cog.plugins import register_default_plugins

    register_default_plugins()
    cogruntime.register_dataquery_variant(cogruntime.DataqueryConfig(INFINITY, InfinityQuery.from_json))


register()


class Query(cogbuilder.Builder[cogvariants.Dataquery]):
    """``Query(ds, "series", [("time", "timestamp"), ("speed", "number")], id=..., attrs=...)``."""

    def __init__(
        self,
        ds: Datasource,
        endpoint: str,
        columns: Sequence[tuple[str, str]],
        *,
        ref_id: str = "A",
        time: bool = True,
        interval: bool = False,
        max_points: int | None = None,
        **params: str,
    ) -> None:
        pairs = [(key, value) for key, value in params.items() if value is not None]
        if time:
            pairs += [("from", "${__from}"), ("to", "${__to}")]
        if interval:
            pairs.append(("interval_ms", "${__interval_ms}"))
        if max_points is not None:
            pairs.append(("max_points", str(max_points)))
        self._query = InfinityQuery(
            refId=ref_id,
            datasource=ds.ref.to_json(),
            type="json",
            source="url",
            parser="backend",
            format="table",
            url=f"{API}/{endpoint}",
            url_options={
                "method": "GET",
                "data": "",
                "params": [{"key": key, "value": value} for key, value in pairs],
                "headers": [],
            },
            root_selector="",
            columns=[{"selector": name, "text": name, "type": kind} for name, kind in columns],
            filters=[],
            computed_columns=[],
        )

    def build(self) -> InfinityQuery:
        return self._query


def attrs(**columns: str) -> str:
    """``attrs(speed="odom(twist.twist.linear.x)")`` → ``speed=odom(twist.twist.linear.x)``."""
    return ",".join(f"{name}={path}" for name, path in columns.items())


# --- mappings, thresholds, colours ------------------------------------------------------------------


def value_mappings(names: dict[int, str], colors: dict[str, str] | None = None) -> list[dm.ValueMap]:
    """Integer codes → names (and colours), from the enumerations the simulators use."""
    colors = colors or {}
    return [
        dm.ValueMap(
            options={
                str(code): dm.ValueMappingResult(text=name, color=colors.get(name), index=i)
                for i, (code, name) in enumerate(names.items())
            }
        )
    ]


def bool_mappings(true_text: str, false_text: str, true_color: str = "red", false_color: str = "green") -> list:
    return [
        dm.ValueMap(
            options={
                "true": dm.ValueMappingResult(text=true_text, color=true_color, index=0),
                "false": dm.ValueMappingResult(text=false_text, color=false_color, index=1),
            }
        )
    ]


def thresholds(base: str, *steps: tuple[float, str]) -> db.ThresholdsConfig:
    return (
        db.ThresholdsConfig()
        .mode(dm.ThresholdsMode.ABSOLUTE)
        .steps([dm.Threshold(value=None, color=base), *(dm.Threshold(value=v, color=c) for v, c in steps)])
    )


def fields_regex(*names: str) -> str:
    return "/^(" + "|".join(names) + ")$/"


# --- panels -------------------------------------------------------------------------------------------


# What a panel takes: any datasource with a ``ref`` (Infinity, Prometheus) and
# any query builder (Infinity, Prometheus, the NGSI-LD drone's).
Target = cogbuilder.Builder[cogvariants.Dataquery]


class SourceRef(typing.Protocol):
    @property
    def ref(self) -> common.DataSourceRef: ...


class Ids:
    """Panel ids in order of creation, unique per dashboard."""

    def __init__(self) -> None:
        self.next = 1

    def __call__(self) -> int:
        value = self.next
        self.next += 1
        return value


def _place(panel, ids: Ids, title: str, w: int, h: int, ds: SourceRef, query: Target, description: str | None):
    panel = panel.id(ids()).title(title).span(w).height(h).datasource(ds.ref).with_target(query)
    return panel.description(description) if description else panel


def stat_panel(
    ids: Ids,
    ds: SourceRef,
    title: str,
    query: Target,
    field: str,
    *,
    w: int = 4,
    h: int = 5,
    unit: str | None = None,
    mappings: list | None = None,
    thresholds_: db.ThresholdsConfig | None = None,
    decimals: float | None = None,
    description: str | None = None,
) -> stat.Panel:
    panel = _place(stat.Panel(), ids, title, w, h, ds, query, description)
    panel = (
        panel.reduce_options(cb.ReduceDataOptions().calcs(["lastNotNull"]).values(False).fields(fields_regex(field)))
        .graph_mode(common.BigValueGraphMode.NONE)
        .color_mode(common.BigValueColorMode.BACKGROUND)
        .text_mode(common.BigValueTextMode.VALUE)
        .no_value("no data yet")
    )
    if unit:
        panel = panel.unit(unit)
    if mappings:
        panel = panel.mappings(mappings)
    if thresholds_ is not None:
        panel = panel.thresholds(thresholds_)
    if decimals is not None:
        panel = panel.decimals(decimals)
    return panel


def gauge_panel(
    ids: Ids,
    ds: SourceRef,
    title: str,
    query: Target,
    field: str,
    *,
    w: int = 4,
    h: int = 5,
    unit: str,
    low: float,
    high: float,
    thresholds_: db.ThresholdsConfig,
    description: str | None = None,
) -> gauge.Panel:
    panel = _place(gauge.Panel(), ids, title, w, h, ds, query, description)
    return (
        panel.reduce_options(cb.ReduceDataOptions().calcs(["lastNotNull"]).values(False).fields(fields_regex(field)))
        .unit(unit)
        .min(low)
        .max(high)
        .decimals(2)
        .thresholds(thresholds_)
        .show_threshold_markers(True)
        .no_value("no data yet")
    )


def timeseries_panel(
    ids: Ids,
    ds: SourceRef,
    title: str,
    query: Target,
    *,
    w: int = 12,
    h: int = 8,
    unit: str | None = None,
    thresholds_: db.ThresholdsConfig | None = None,
    threshold_style: common.GraphThresholdsStyleMode | None = None,
    draw_style: common.GraphDrawStyle = common.GraphDrawStyle.LINE,
    description: str | None = None,
    max_points: int | None = None,
) -> timeseries.Panel:
    panel = _place(timeseries.Panel(), ids, title, w, h, ds, query, description)
    panel = (
        panel.draw_style(draw_style)
        .line_width(1)
        .fill_opacity(10)
        .show_points(common.VisibilityMode.NEVER)
        .span_nulls(True)
        .legend(
            cb.VizLegendOptions()
            .show_legend(True)
            .display_mode(common.LegendDisplayMode.LIST)
            .placement(common.LegendPlacement.BOTTOM)
            .calcs([])
        )
        .tooltip(cb.VizTooltipOptions().mode(common.TooltipDisplayMode.MULTI).sort(common.SortOrder.NONE))
    )
    if unit:
        panel = panel.unit(unit)
    if thresholds_ is not None:
        panel = panel.thresholds(thresholds_)
    if threshold_style is not None:
        panel = panel.thresholds_style(cb.GraphThresholdsStyleConfig().mode(threshold_style))
    if max_points is not None:
        panel = panel.max_data_points(max_points)
    return panel


def state_timeline_panel(
    ids: Ids,
    ds: SourceRef,
    title: str,
    query: Target,
    mappings: list,
    *,
    w: int = 24,
    h: int = 5,
    description: str | None = None,
) -> statetimeline.Panel:
    """Every field of the panel shares ``mappings``: one enumeration per panel
    (field overrides do not pass the dashboard JSON Schema)."""
    panel = _place(statetimeline.Panel(), ids, title, w, h, ds, query, description)
    panel = (
        panel.show_value(common.VisibilityMode.AUTO)
        .merge_values(True)
        .row_height(0.8)
        .line_width(0)
        .fill_opacity(80)
        .align_value("left")
        .legend(
            cb.VizLegendOptions()
            .show_legend(False)
            .display_mode(common.LegendDisplayMode.LIST)
            .placement(common.LegendPlacement.BOTTOM)
            .calcs([])
        )
        .tooltip(cb.VizTooltipOptions().mode(common.TooltipDisplayMode.SINGLE).sort(common.SortOrder.NONE))
    )
    return panel.mappings(mappings)


def row(ids: Ids, title: str) -> db.Row:
    return db.Row(title).id(ids()).collapsed(False)


def annotation(name: str, ds: SourceRef, query: Target, color: str) -> db.AnnotationQuery:
    return db.AnnotationQuery().name(name).datasource(ds.ref).enable(True).icon_color(color).target(query)


def dashboard(uid: str, title: str, description: str, tags: list[str], time_from: str, refresh: str) -> db.Dashboard:
    return (
        db.Dashboard(title)
        .uid(uid)
        .description(description)
        .tags(["tsdb-service", "fiware", *tags])
        .timezone("browser")
        .time(time_from, "now")
        .refresh(refresh)
        .tooltip(dm.DashboardCursorSync.CROSSHAIR)
        .editable()
        .timepicker(db.TimePicker().refresh_intervals(["5s", "10s", "30s", "1m", "5m"]))
        .link(
            db.DashboardLink("tsdb-service dashboards")
            .type(dm.DashboardLinkType.DASHBOARDS)
            .tags(["tsdb-service"])
            .as_dropdown(True)
            .include_vars(False)
            .keep_time(True)
        )
    )


def to_json(builder: db.Dashboard) -> dict:
    """The dashboard as plain JSON data (what Grafana stores)."""
    import json

    from grafana_foundation_sdk.cog.encoder import JSONEncoder

    return json.loads(json.dumps(builder.build(), cls=JSONEncoder))
