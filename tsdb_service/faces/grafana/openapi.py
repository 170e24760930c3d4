"""The Grafana routes' part of the OpenAPI description (Infinity, SimpleJSON, dashboards)."""

from __future__ import annotations

from tsdb_service.http.openapi import (
    ANY,
    AUTH,
    FIWARE_SERVICE,
    GEO,
    NGSILD_TENANT,
    NULLABLE_STR,
    READ_ERRORS,
    SERVICE_PATH_QUERY,
    SP_QUERY,
    STR,
    STRS,
    TENANT_SCHEMA,
    array,
    json_body,
    obj,
    ok,
    query,
    ref,
    spec,
)

_FRAME_FIELD = obj(
    ("name", "type", "values"),
    {
        "name": STR,
        "type": STR,
        "values": array(ANY),
        "labels": {"type": "object"},
        "config": {"type": "object", "description": "the time field's interval: the bucket width in ms"},
    },
)
# What a drawn answer says about itself (docs/long-windows.md): its bucket
# width, its mode, and what a cap left out (Grafana shows notices on the panel).
_META = {
    "type": "object",
    "properties": {
        "custom": {
            "type": "object",
            "properties": {"bucket": STR, "bucketMs": {"type": "integer"}, "agg": STR},
        },
        "notices": array(obj(("severity", "text"), {"severity": STR, "text": STR})),
    },
}


_GRAFANA_TENANCY = [
    FIWARE_SERVICE,
    NGSILD_TENANT,
    SERVICE_PATH_QUERY,
    query(
        "service", "Tenant, for datasources that cannot send headers; must agree with Fiware-Service.", TENANT_SCHEMA
    ),
    query("servicepath", "Service paths, as the Fiware-ServicePath header.", SP_QUERY),
]


_GRAFANA_ENTITIES = [
    query("id", "Entity ids, comma-separated (at most 1000)."),
    query("idPattern", "Entity id regular expression (RE2 syntax)."),
    query("type", "Entity types, comma-separated (at most 100)."),
]


_GRAFANA_TIME = [
    query("from", "Start: epoch milliseconds (Grafana's ${__from}) or ISO 8601."),
    query("to", "End: epoch milliseconds or ISO 8601."),
]


_COLUMNS = "Columns: attribute names or value paths, each optionally alias=path, comma-separated (at most 64)."


_POINTS = {"type": "number", "minimum": 1}


def grafana_params(*extra: dict, attrs: bool | None = True, time: bool = True) -> list[dict]:
    """The Infinity endpoints' parameters: tenancy, entities, ``attrs``
    (required, optional or absent), the time range, then ``extra``."""
    params = [*_GRAFANA_TENANCY, *_GRAFANA_ENTITIES]
    if attrs is not None:
        params.append(query("attrs", _COLUMNS, required=attrs))
    if time:
        params += _GRAFANA_TIME
    return params + list(extra)


MAX_POINTS = query(
    "max_points", "Points per series: more samples than this are drawn in buckets (capped at 100000).", _POINTS
)


GRAFANA_LIMIT = query("limit", "At most this many rows (capped at 100000).", _POINTS)


_GRAFANA_ERRORS = READ_ERRORS


def _rows(*required: str) -> dict:
    """Infinity's flat rows: the named keys always, a key per column besides."""
    return array({"type": "object", "required": list(required)}) if required else ref("InfinityRows")


def _infinity(rows: dict, *parameters: dict, attrs: bool | None = True, time: bool = True) -> dict:
    return spec(*grafana_params(*parameters, attrs=attrs, time=time), ok_=ok(rows), errors_=_GRAFANA_ERRORS)


_AGG = ["auto", "avg", "min", "max", "first", "last", "sum", "count", "minmax"]  # grafana.frames.AGGREGATIONS
_FILL = ["none", "null", "previous", "linear"]  # grafana.frames.FILLS
_DRAWN = (
    " The answer's X-Tsdb-Bucket header gives the bucket width (raw: the samples as stored; X-Tsdb-Bucket-Ms "
    "in milliseconds); X-Tsdb-Truncated and X-Tsdb-Notice say what a cap left out."
)


INFINITY = {
    "series": _infinity(
        _rows("time"),
        MAX_POINTS,
        query("interval_ms", "Minimum bucket width in milliseconds.", {"type": "number", "minimum": 1}),
        query(
            "agg",
            "What a bucket shows: auto (avg where a series holds fractions, last where it holds integers), avg, "
            "min, max, first, last, sum, count, or minmax (first, min, max and last at their times)." + _DRAWN,
            {"enum": _AGG},
        ),
        query("fill", "What an empty bucket shows: none (a gap: one null), null, previous or linear.", {"enum": _FILL}),
        query("layout", "long: a row per entity and time; wide: a row per time.", {"enum": ["long", "wide"]}),
    ),
    "latest": _infinity(_rows("entity", "type", "name"), time=False),
    "states": _infinity(_rows("time", "entity"), MAX_POINTS),
    "events": _infinity(
        _rows("time", "timeEnd", "entity", "title", "text", "tags"),
        query("equals", "A JSON value: an event is a run of samples equal to it (default: truthy)."),
        query("text", "Event text."),
        GRAFANA_LIMIT,
    ),
    "positions": _infinity(
        _rows("time", "entity", "type", "name", "lat", "lon"),
        query("location", "Attribute or value path holding the position (default location)."),
        query(
            "latest",
            "Only each entity's latest position.",
            {"enum": ["true", "false", "1", "0", "yes", "no", "on", "off"]},
        ),
        MAX_POINTS,
        *GEO,
        attrs=False,
    ),
    "aggregate": _infinity(
        _rows("entity", "type", "name"),
        query("method", "Aggregate.", {"enum": ["avg", "min", "max", "sum", "count"]}),
        query(
            "period",
            "One aggregate per period instead of per entity.",
            {"enum": ["", "second", "minute", "hour", "day", "month", "year"]},
        ),
        GRAFANA_LIMIT,
    ),
    "entities": _infinity(_rows("entity", "type", "name", "attrs"), attrs=None, time=False),
}


_SJ_TENANCY = _GRAFANA_TENANCY


_OPEN_BODY = {"type": "object", "description": "Grafana's request; unknown members are ignored"}


def _simplejson(answer: dict, body: dict | None = None, example: dict | None = None) -> dict:
    schema = {**_OPEN_BODY, **(body or {})}
    return spec(
        *_SJ_TENANCY,
        ok_=ok(answer),
        errors_=_GRAFANA_ERRORS,
        body=json_body(schema, required=False, examples={"example": example} if example else None),
    )


_LABEL_VALUE = obj(("label", "value"), {"label": STR, "value": STR})


_RANGE = {
    "type": "object",
    "properties": {"from": {"type": ["string", "number"]}, "to": {"type": ["string", "number"]}},
}


_TARGET = {
    "type": "object",
    "properties": {
        "target": {"type": "string", "description": "<entity id or *>/<attribute or value path>"},
        "refId": STR,
        "type": STR,
        "hide": {"type": "boolean"},
        "payload": {
            "type": "object",
            "properties": {
                "path": STR,
                "type": STR,
                "idPattern": STR,
                "alias": STR,
                "agg": {"enum": _AGG},
                "fill": {"enum": _FILL},
                "format": {"enum": ["timeseries", "table", "dataframe", "annotations"]},
                "equals": ANY,
            },
        },
    },
}


SIMPLEJSON = {
    "test": spec(
        *_SJ_TENANCY,
        ok_=ok(
            obj(("status", "tenant", "servicePaths"), {"status": {"const": "ok"}, "tenant": STR, "servicePaths": STRS})
        ),
        errors_=_GRAFANA_ERRORS,
    ),
    "search": _simplejson(STRS, {"properties": {"target": STR}}, {"target": ""}),
    "variable": _simplejson(
        array(obj(("__text", "__value"), {"__text": STR, "__value": STR})),
        {"properties": {"payload": {"anyOf": [STR, {"type": "object", "properties": {"target": STR}}]}}},
        {"payload": {"target": "entities"}},
    ),
    "metrics": _simplejson(
        array(obj(("label", "value", "payloads"), {"label": STR, "value": STR, "payloads": array({"type": "object"})})),
        {"properties": {"metric": STR}},
    ),
    "metric-payload-options": _simplejson(
        array(_LABEL_VALUE),
        {"properties": {"metric": STR, "name": STR, "payload": {"type": "object"}}},
        {"metric": "*/location", "name": "path"},
    ),
    "query": _simplejson(
        array(ref("SimpleJsonAnswer")),
        {
            "properties": {
                "range": _RANGE,
                "intervalMs": {"type": "number"},
                "maxDataPoints": {"type": "number"},
                "targets": {**array(_TARGET), "maxItems": 50},
                "adhocFilters": array({"type": "object"}),
            }
        },
        {
            "range": {"from": "2024-05-01T00:00:00Z", "to": "2024-05-02T00:00:00Z"},
            "targets": [{"target": "*/temperature", "refId": "A"}],
        },
    ),
    "annotations": _simplejson(
        array({"type": "object", "required": ["annotation", "time", "timeEnd", "isRegion", "title", "text", "tags"]}),
        {"properties": {"range": _RANGE, "annotation": {"type": "object", "properties": {"query": STR}}}},
    ),
    "tag-keys": _simplejson(array(obj(("type", "text"), {"type": STR, "text": STR}))),
    "tag-values": _simplejson(array(obj(("text",), {"text": STR})), {"properties": {"key": STR}}),
}


DASHBOARDS = spec(
    ok_=ok(
        array(
            obj(
                (
                    "name",
                    "use_case",
                    "uid",
                    "title",
                    "description",
                    "sections",
                    "tags",
                    "url",
                    "datasource_uid",
                    "datasources",
                ),
                {
                    "name": STR,
                    "use_case": NULLABLE_STR,
                    "uid": STR,
                    "title": STR,
                    "description": STR,
                    "sections": array(obj(("title", "panels"), {"title": NULLABLE_STR, "panels": STRS})),
                    "tags": STRS,
                    "url": STR,
                    "datasource_uid": NULLABLE_STR,
                    "datasources": array(obj(("type", "uid"), {"type": NULLABLE_STR, "uid": STR})),
                },
            )
        )
    ),
    errors_=AUTH,
)


DASHBOARD = spec(ok_=ok(ref("Dashboard")), errors_=(*AUTH, 404))


PROVISIONING = spec(
    query(
        "url",
        "datasources.yaml: where Grafana reaches this service, http(s)://host[:port][/path] "
        "(default http://tsdb-service:8668).",
        {"type": "string", "maxLength": 200},
    ),
    ok_=ok({"type": "object"}, "A Grafana provisioning file: YAML, one mapping (apiVersion, ...)", "application/yaml"),
    errors_=(400, *AUTH, 404),
)


SCHEMAS: dict[str, dict] = {
    "InfinityRows": array({"type": "object"}, "flat rows, one object each; columns named by attrs"),
    "SimpleJsonAnswer": {
        "anyOf": [
            obj(
                ("target", "datapoints"),
                {"target": STR, "refId": STR, "datapoints": array(array(ANY)), "meta": _META},
            ),
            obj(
                ("type", "columns", "rows"),
                {
                    "type": {"const": "table"},
                    "refId": STR,
                    "columns": array({"type": "object"}),
                    "rows": array(array(ANY)),
                    "meta": _META,
                },
            ),
            obj(("name", "fields"), {"name": STR, "refId": STR, "fields": array(_FRAME_FIELD), "meta": _META}),
        ]
    },
    "Dashboard": {"type": "object", "description": "A Grafana dashboard (schemaVersion 42)"},
}
