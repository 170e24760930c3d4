"""``/grafana/infinity/*``: flat JSON rows for the Infinity datasource.

Infinity (``yesoreyeram-infinity-datasource``) reads any JSON URL; these GET
endpoints answer with arrays of flat objects that its backend parser turns
into frames. Common query parameters:

* tenant: ``Fiware-Service`` / ``Fiware-ServicePath`` headers (custom headers
  on the datasource) or ``service`` / ``servicepath`` parameters;
* entities: ``id`` (comma list), ``idPattern`` (regex), ``type``;
* columns: ``attrs=name=path,...``: attributes or value paths such as
  ``speed=odom(twist.twist.linear.x)``; a row carries each under its name;
* time: ``from`` / ``to`` as epoch ms (Grafana's ``${__from}``) or ISO 8601.

Times in rows are ISO 8601 UTC with milliseconds and a ``Z``. What draws a
window reads the database's time buckets (``history.drawing``); answers say
their bucket width and anything a cap left out in headers
(``http.responses.drawn_headers``): rows of flat JSON have no room for it.
Routes read the store through ``Store.read`` (``@reads_store``): in the threadpool.
"""

from __future__ import annotations

from fastapi import APIRouter, Request

from tsdb_service.faces.grafana import frames
from tsdb_service.faces.grafana import openapi as grafana_oa
from tsdb_service.faces.grafana.params import (
    MAX_POINTS_LIMIT,
    aggregate_method,
    aggregate_period,
    choice,
    columns,
    entity_filter,
    fill_choice,
    flag,
    positive_int,
    time_range,
)
from tsdb_service.geo.filter import parse_geo
from tsdb_service.history.valuepath import parse_value_path
from tsdb_service.http.responses import JSON
from tsdb_service.http.store import reads_store, store_of
from tsdb_service.http.tenancy import grafana_scope
from tsdb_service.read.requests import SeriesSelect

router = APIRouter(prefix="/grafana/infinity", tags=["grafana"])


def _common(request: Request):
    params = request.query_params
    return store_of(request).querier(), grafana_scope(request), entity_filter(params), params


@router.get(
    "/series",
    summary="Time series of columns per entity, in at most max_points buckets",
    **grafana_oa.INFINITY["series"],
)
@reads_store
def series(request: Request) -> JSON:
    """``[{"time", "entity", col...}]`` over the whole window: the samples as
    stored while each series has at most ``max_points`` (default 1000) in
    it, else time buckets computed by the database (width from the window and
    ``max_points``, at least ``interval_ms``, a round width) reduced by
    ``agg``: ``auto`` (avg where a series holds fractions, last where it
    holds integers only), avg, last, first, min, max, sum, count, or
    ``minmax`` (first, min, max and last of each bucket at their times).
    Texts and booleans: every transition. An empty bucket is a gap (a null),
    or filled by ``fill`` (null, previous, linear). ``layout=wide`` gives one
    row per time and a column per entity and column."""
    querier, scope, entities, params = _common(request)
    query = frames.series_query(
        scope,
        entities,
        columns(params.get("attrs")),
        time_range(params),
        max_points=positive_int(params.get("max_points"), "max_points", 1000, MAX_POINTS_LIMIT),
        interval_ms=positive_int(params.get("interval_ms"), "interval_ms", None, 10**12),
        agg=choice(params.get("agg"), "agg", frames.AGGREGATIONS, "auto"),
        fill=fill_choice(params.get("fill")),
    )
    wide = choice(params.get("layout"), "layout", ("long", "wide"), "long") == "wide"
    shown = frames.series_rows(querier, query, wide)
    return JSON(shown.rows, headers=shown.headers())


@router.get(
    "/latest", summary="Latest value of each column per entity (gauges, stats)", **grafana_oa.INFINITY["latest"]
)
@reads_store
def latest(request: Request) -> JSON:
    """``[{"entity", "type", "name", "time", col...}]``, one row per entity."""
    querier, scope, entities, params = _common(request)
    return JSON(frames.latest_rows(querier, scope, entities, columns(params.get("attrs"))))


@router.get(
    "/states",
    summary="State changes (state timelines)",
    **grafana_oa.INFINITY["states"],
)
@reads_store
def states(request: Request) -> JSON:
    """``[{"time", "entity", col...}]``: a row where any column changes, and
    each entity's last sample: every transition, at most ``max_points``
    (default 5000) per entity and column, the newest (a header says so)."""
    querier, scope, entities, params = _common(request)
    shown = frames.state_rows(
        querier,
        scope,
        entities,
        columns(params.get("attrs")),
        time_range(params),
        max_points=positive_int(params.get("max_points"), "max_points", 5000, MAX_POINTS_LIMIT),
    )
    return JSON(shown.rows, headers=shown.headers())


@router.get(
    "/events",
    summary="Events as annotations (e.g. perimeter detections)",
    **grafana_oa.INFINITY["events"],
)
@reads_store
def events(request: Request) -> JSON:
    """``[{"time", "timeEnd", "entity", "title", "text", "tags"}]``: one per
    run of samples where a column is truthy, or ``== equals`` (a JSON value);
    the newest ``limit`` (default 1000; a header says when there were more)."""
    querier, scope, entities, params = _common(request)
    shown = frames.event_rows(
        querier,
        scope,
        entities,
        columns(params.get("attrs")),
        time_range(params),
        matches=frames.condition(params.get("equals")),
        text=(params.get("text") or None),
        limit=positive_int(params.get("limit"), "limit", 1000, MAX_POINTS_LIMIT),
    )
    return JSON(shown.rows, headers=shown.headers())


@router.get(
    "/positions",
    summary="Positions (geomap markers and heatmaps)",
    **grafana_oa.INFINITY["positions"],
)
@reads_store
def positions(request: Request) -> JSON:
    """``[{"time", "entity", "type", "name", "lat", "lon", col...}]``. ``location``
    names the attribute or value path holding the position (default
    ``location``; GeoJSON or ``"lat, lon"``). ``latest=true`` keeps each
    entity's latest position with its columns' latest values. ``georel``,
    ``geometry`` and ``coords`` (NGSIv2 geo-query) keep matching positions.
    Over ``max_points`` (default 5000) positions an entity, the last position
    of each time bucket (a header gives the width)."""
    querier, scope, entities, params = _common(request)
    geo = parse_geo(params.get("georel"), params.get("geometry"), params.get("coords"))
    shown = frames.position_rows(
        querier,
        scope,
        entities,
        parse_value_path(params.get("location") or "location"),
        columns(params.get("attrs"), required=False),
        time_range(params),
        latest=flag(params.get("latest"), "latest"),
        max_points=positive_int(params.get("max_points"), "max_points", 5000, MAX_POINTS_LIMIT),
        geo=geo,
    )
    return JSON(shown.rows, headers=shown.headers())


@router.get(
    "/aggregate",
    summary="One aggregate per entity (or per period)",
    **grafana_oa.INFINITY["aggregate"],
)
@reads_store
def aggregate(request: Request) -> JSON:
    """``[{"entity", "type", "name", ("time",) col...}]``; ``method`` avg
    (default), min, max, sum, count; optional ``period`` (second ... year);
    at most ``limit`` rows (default 10000; a header says when there were more)."""
    querier, scope, entities, params = _common(request)
    shown = frames.aggregate_rows(
        querier,
        scope,
        entities,
        columns(params.get("attrs")),
        time_range(params),
        method=aggregate_method(params.get("method")),
        period=aggregate_period(params.get("period")),
        limit=positive_int(params.get("limit"), "limit", 10_000, MAX_POINTS_LIMIT),
    )
    return JSON(shown.rows, headers=shown.headers())


@router.get(
    "/entities",
    summary="Entities of the tenant (template variables)",
    **grafana_oa.INFINITY["entities"],
)
@reads_store
def entities(request: Request) -> JSON:
    """``[{"entity", "type", "name", "attrs"}]``: ids, types and attribute names."""
    querier, scope, entities, _ = _common(request)
    found: dict[tuple[str, str], set[str]] = {}
    for ref in querier.series(SeriesSelect(scope, entities)):
        found.setdefault((ref.entity_id, ref.entity_type), set()).add(ref.attr)
    return JSON(
        [
            {"entity": eid, "type": etype, "name": frames.short_name(eid), "attrs": ",".join(sorted(attrs))}
            for (eid, etype), attrs in sorted(found.items())
        ]
    )
