"""``/grafana/simplejson/*``: the SimpleJSON family (classic SimpleJSON, simPod JSON).

Point the datasource's URL at ``http://<host>:8668/grafana/simplejson`` and
give the tenant as custom headers ``Fiware-Service`` / ``Fiware-ServicePath``.

A *target* (metric) names one column of some entities:
``<entity id>/<attribute or value path>``, e.g.
``urn:ngsiv2:ROS2System:Lawnmower01/odom(twist.twist.linear.x)``, split at
the first ``/``. Ids (NGSI-LD URIs) and attribute names may contain ``/``
themselves, so inside either part ``%2F`` stands for ``/`` and ``%25`` for
``%``, as in history URL paths: ``urn:a%2Fb/v`` is attribute ``v`` of
``urn:a/b``, ``urn:a/b%2Fv`` attribute ``b/v`` of ``urn:a``. ``/search``,
``/metrics`` and the ``entities`` / ``attrs`` variables list names in that
form, so whatever they list is a valid target. ``*`` instead of an id means
every entity (narrowed by the payload's ``type`` or ``idPattern``). simPod's
payload (or SimpleJSON's ``data``) may add ``path``
(steps inside the value, appended to a plain attribute), ``agg`` (auto, avg,
last, min, max, first, sum, count, minmax), ``fill`` (none, null, previous,
linear), ``alias`` and ``format`` (``timeseries``, ``table``,
``dataframe``, ``annotations``). An annotation query is a target optionally
followed by ``=<JSON value>``: ``.../perimeterLeft(data)=true``.

``/query`` draws the whole range in at most ``maxDataPoints`` points per
series, with buckets at least ``intervalMs`` wide, computed by the database
(``history.drawing``); each frame says its bucket width and what a cap left
out (``meta.notices``, and the ``X-Tsdb-*`` headers).

Unknown keys anywhere in a body are ignored: simPod posts Grafana's whole
request object. Routes that read the store do so through ``Store.read``
(``@reads_store``, in the threadpool); FastAPI parses the body first.
"""

from __future__ import annotations

import re
from typing import Any

from fastapi import APIRouter, Body, Request

from tsdb_service.core import budget
from tsdb_service.core.buckets import label
from tsdb_service.core.errors import BadRequest
from tsdb_service.core.idpattern import compile_pattern, compiled
from tsdb_service.core.query import EntityFilter, LastValueQuery, Scope, TimeRange, ValuePath
from tsdb_service.faces.grafana import frames
from tsdb_service.faces.grafana import openapi as grafana_oa
from tsdb_service.faces.grafana.params import MAX_POINTS_LIMIT, Column, moment, positive_int
from tsdb_service.history.drawing import Drawing, Mode, Track, draw
from tsdb_service.history.service import run_last_values
from tsdb_service.history.valuepath import parse_value_path
from tsdb_service.http.rawpath import escape_segment, unescape_segment
from tsdb_service.http.responses import JSON, drawn_headers
from tsdb_service.http.store import reads_store, store_of
from tsdb_service.http.tenancy import grafana_scope
from tsdb_service.parse.request_context import id_pattern
from tsdb_service.read import HistoryReads
from tsdb_service.read.requests import SeriesSelect

router = APIRouter(prefix="/grafana/simplejson", tags=["grafana"])

FORMATS = ("timeseries", "table", "dataframe", "annotations")
_MAX_TARGETS = 50


# --- parsing -------------------------------------------------------------------------------------


def _obj(value: Any) -> dict:
    return value if isinstance(value, dict) else {}


def _str(value: Any, name: str, default: str = "") -> str:
    if value is None:
        return default
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        return str(value)
    if not isinstance(value, str):
        raise BadRequest(f"{name} must be a string")
    return value


def _range(body: dict) -> TimeRange:
    rng = _obj(body.get("range"))
    start = moment(_when(rng.get("from")), "range.from")
    end = moment(_when(rng.get("to")), "range.to")
    if start is not None and end is not None and start > end:
        raise BadRequest("range.from must not be after range.to")
    return TimeRange(start, end)


def _when(value: Any) -> str | None:
    if value is None:
        return None
    if isinstance(value, bool):
        raise BadRequest("range bounds must be ISO 8601 strings or epoch milliseconds")
    if isinstance(value, (int, float)):
        return str(int(value))
    if isinstance(value, str):
        return value
    raise BadRequest("range bounds must be ISO 8601 strings or epoch milliseconds")


def target_part(text: str) -> str:
    """An entity id or attribute name as written in a target (``/`` and ``%`` escaped)."""
    return escape_segment(text)


def target_name(entity_id: str, attr: str) -> str:
    """The target that names ``attr`` of ``entity_id``: what ``split_target`` reads back."""
    return f"{target_part(entity_id)}/{target_part(attr)}"


def split_target(text: str) -> tuple[str, str] | None:
    """``<id>/<attribute or value path>`` → the two parts unescaped, or None
    when a part is missing. The first ``/`` separates: any ``/`` inside a
    part is written ``%2F``."""
    entity, sep, path = text.partition("/")
    if not sep or not entity or not path:
        return None
    return unescape_segment(entity), unescape_segment(path)


class Target:
    """A parsed target: which entities, which column, how to answer."""

    def __init__(self, raw: dict, default_type: str | None = None):
        text = _str(raw.get("target"), "target").strip()
        payload = raw.get("payload")
        if not isinstance(payload, dict):
            data = raw.get("data")
            payload = data if isinstance(data, dict) else {}
        self.ref_id = _str(raw.get("refId"), "refId", "A")
        parts = split_target(text)
        if parts is None:
            raise BadRequest(
                f"target {text[:80]!r} must be <entity id or *>/<attribute or value path> "
                "('/' inside the id or the attribute written as %2F)"
            )
        entity, path_text = parts
        path = parse_value_path(path_text)
        extra = _str(payload.get("path"), "payload.path").strip()
        if extra and not path.steps:
            path = parse_value_path(f"{path.attr}({extra})")
        types = _str(payload.get("type"), "payload.type").strip() or None
        pattern = id_pattern(_str(payload.get("idPattern"), "payload.idPattern").strip(), "payload.idPattern")
        ids = None if entity == "*" else (entity,)
        self.entities = EntityFilter(ids=ids, id_pattern=pattern, types=(types,) if types else None)
        self.alias = _str(payload.get("alias"), "payload.alias").strip() or None
        self.column = Column(self.alias or path.text, path)
        self.agg = _str(payload.get("agg"), "payload.agg", "auto").strip().lower() or "auto"
        if self.agg not in frames.AGGREGATIONS:
            raise BadRequest(f"payload.agg must be one of {', '.join(frames.AGGREGATIONS)}")
        self.fill = _str(payload.get("fill"), "payload.fill", "none").strip().lower() or "none"
        if self.fill not in frames.FILLS:
            raise BadRequest(f"payload.fill must be one of {', '.join(frames.FILLS)}")
        fmt = _str(payload.get("format"), "payload.format").strip().lower()
        kind = _str(raw.get("type"), "type").strip().lower()
        if not fmt:
            fmt = {"table": "table", "dataframe": "dataframe"}.get(kind, default_type or "timeseries")
        if fmt == "timeserie":
            fmt = "timeseries"
        if fmt not in FORMATS:
            raise BadRequest(f"payload.format must be one of {', '.join(FORMATS)}")
        self.format = fmt
        self.equals = payload.get("equals")


def _adhoc(body: dict) -> list[tuple[str, str, str]]:
    """Ad hoc filters on ``entity`` / ``type`` / ``name``: =, !=, =~, !~."""
    raw = body.get("adhocFilters")
    if raw is None:
        raw = body.get("filters")
    out = []
    for item in raw if isinstance(raw, list) else []:
        if not isinstance(item, dict):
            continue
        key, op, value = item.get("key"), item.get("operator", "="), item.get("value")
        if key not in ("entity", "type", "name") or not isinstance(value, str) or op not in ("=", "!=", "=~", "!~"):
            continue
        if op in ("=~", "!~"):
            compile_pattern(value, f"ad hoc filter {key} {op} {value[:40]!r}")
        out.append((key, op, value))
    return out


def _keep(entity_id: str, entity_type: str, filters: list[tuple[str, str, str]]) -> bool:
    for key, op, value in filters:
        subject = {"entity": entity_id, "type": entity_type, "name": frames.short_name(entity_id)}[key]
        if op == "=":
            ok = subject == value
        elif op == "!=":
            ok = subject != value
        else:
            ok = compiled(value).search(subject) is not None
            ok = ok if op == "=~" else not ok
        if not ok:
            return False
    return True


def _number(value):
    if isinstance(value, bool):
        return int(value)
    if isinstance(value, (int, float)):
        return value
    return None


def _kind(values: list) -> str:
    present = [v for v in values if v is not None]
    if present and all(isinstance(v, bool) for v in present):
        return "boolean"
    if present and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in present):
        return "number"
    return "string"


def _cell(value, kind: str):
    if value is None or kind != "string" or isinstance(value, str):
        return value
    return frames._text(value)


# --- routes -----------------------------------------------------------------------------------------------


@router.get("", include_in_schema=False)
@router.get("/", summary="Test connection (SimpleJSON / simPod)", **grafana_oa.SIMPLEJSON["test"])
def test_connection(request: Request) -> JSON:
    scope = grafana_scope(request)
    return JSON({"status": "ok", "tenant": scope.tenant, "servicePaths": list(scope.service_paths)})


def _catalog(request: Request, entities: EntityFilter | None = None) -> dict[tuple[str, str], set[str]]:
    scope = grafana_scope(request)
    found: dict[tuple[str, str], set[str]] = {}
    for ref in store_of(request).querier().series(SeriesSelect(scope, entities or EntityFilter())):
        found.setdefault((ref.entity_id, ref.entity_type), set()).add(ref.attr)
    return found


def _keyword(request: Request, text: str) -> list[str] | None:
    """Variable queries: ``entities[:Type]``, ``types``, ``attrs[:entity id]``.
    Entity ids and attribute names come in target form (``target_part``), so
    ``$entity/$attr`` is a valid target; ``attrs:`` takes an id in that form."""
    word, _, arg = text.strip().partition(":")
    word = word.strip().lower()
    arg = arg.strip()
    if word == "entities":
        catalog = _catalog(request, EntityFilter(types=(arg,)) if arg else None)
        return sorted({target_part(eid) for eid, _ in catalog})
    if word == "types":
        return sorted({etype for _, etype in _catalog(request)})
    if word == "attrs":
        catalog = _catalog(request, EntityFilter(ids=(unescape_segment(arg),)) if arg else None)
        return sorted({target_part(attr) for attrs in catalog.values() for attr in attrs})
    return None


def _metric_names(request: Request, contains: str = "") -> list[str]:
    names = sorted({target_name(eid, attr) for (eid, _), attrs in _catalog(request).items() for attr in attrs})
    return [n for n in names if contains in n] if contains else names


@router.post(
    "/search",
    summary="Metric names, or variable values (SimpleJSON)",
    **grafana_oa.SIMPLEJSON["search"],
)
@reads_store
def search(request: Request, body: Any = Body(None)) -> JSON:
    """``{"target": ""}`` → every ``<entity>/<attribute>``; ``entities``,
    ``entities:<type>``, ``types``, ``attrs``, ``attrs:<entity>`` → names;
    any other text filters the metric names by substring."""
    text = _str(_obj(body).get("target"), "target").strip()
    named = _keyword(request, text)
    return JSON(named if named is not None else _metric_names(request, text))


@router.post(
    "/variable",
    summary="Values of a query variable (simPod)",
    **grafana_oa.SIMPLEJSON["variable"],
)
@reads_store
def variable(request: Request, body: Any = Body(None)) -> JSON:
    """``{"payload": {"target": "entities"}}`` (or a string) → ``[{"__text", "__value"}]``."""
    payload = _obj(body).get("payload")
    text = _str(payload.get("target") if isinstance(payload, dict) else payload, "payload.target").strip()
    named = _keyword(request, text)
    values = named if named is not None else _metric_names(request, text)
    return JSON(
        [{"__text": frames.short_name(unescape_segment(v)) if named is not None else v, "__value": v} for v in values]
    )


_PAYLOADS = [
    {
        "label": "Path inside the value",
        "name": "path",
        "type": "select",
        "placeholder": "e.g. twist.twist.linear.x",
        "width": 40,
    },
    {
        "label": "Downsampling",
        "name": "agg",
        "type": "select",
        "width": 20,
        "options": [{"label": a, "value": a} for a in frames.AGGREGATIONS],
    },
    {
        "label": "Empty buckets",
        "name": "fill",
        "type": "select",
        "width": 20,
        "options": [{"label": f, "value": f} for f in frames.FILLS],
    },
    {
        "label": "Format",
        "name": "format",
        "type": "select",
        "width": 20,
        "options": [{"label": f, "value": f} for f in FORMATS],
    },
    {"label": "Alias", "name": "alias", "type": "input", "placeholder": "field name", "width": 20},
]


@router.post(
    "/metrics", summary="Metrics with their payload options (simPod builder)", **grafana_oa.SIMPLEJSON["metrics"]
)
@reads_store
def metrics(request: Request, body: Any = Body(None)) -> JSON:
    """``[{"label", "value": "<entity>/<attribute>", "payloads": [...]}]``."""
    current = _str(_obj(body).get("metric"), "metric").strip()
    names = _metric_names(request)
    if current and current in names:
        names = [current] + [n for n in names if n != current]
    out = []
    for name in names:
        parts = split_target(name)
        if parts is None:  # every metric name is a target we built: <id>/<attr>
            continue
        eid, attr = parts
        out.append({"label": f"{frames.short_name(eid)} {attr}", "value": name, "payloads": _PAYLOADS})
    return JSON(out)


@router.post(
    "/metric-payload-options",
    summary="Options of one payload field (simPod builder)",
    **grafana_oa.SIMPLEJSON["metric-payload-options"],
)
@reads_store
def metric_payload_options(request: Request, body: Any = Body(None)) -> JSON:
    """``{"metric", "payload", "name"}`` → ``[{"label", "value"}]``. For
    ``path``: the leaf paths found in the metric's latest value."""
    doc = _obj(body)
    name = _str(doc.get("name"), "name").strip()
    if name == "agg":
        return JSON([{"label": a, "value": a} for a in frames.AGGREGATIONS])
    if name == "format":
        return JSON([{"label": f, "value": f} for f in FORMATS])
    if name == "fill":
        return JSON([{"label": f, "value": f} for f in frames.FILLS])
    if name == "type":
        return JSON([{"label": t, "value": t} for t in sorted({t for _, t in _catalog(request)})])
    if name != "path":
        return JSON([])
    metric = _str(doc.get("metric"), "metric").strip()
    parts = split_target(metric)
    if parts is None:
        return JSON([])
    eid, attr = parts
    path = parse_value_path(attr)
    scope = grafana_scope(request)
    ids = None if eid == "*" else (eid,)
    found = run_last_values(
        store_of(request).querier(), LastValueQuery(scope, (EntityFilter(ids=ids),), (ValuePath(path.attr),))
    )
    leaves: list[str] = []
    for ent in found:
        _leaves(ent.get(path.attr, {}).get("value"), "", leaves)
    unique = list(dict.fromkeys(leaves))[:500]
    return JSON([{"label": p, "value": p} for p in unique])


def _leaves(value, prefix: str, out: list[str], depth: int = 0) -> None:
    if depth > 8 or len(out) > 500:
        return
    if isinstance(value, dict):
        for key, inner in value.items():
            if re.fullmatch(r"""[^\s.,\[\]()<>"'=;]+""", key):
                _leaves(inner, f"{prefix}.{key}" if prefix else key, out, depth + 1)
    elif isinstance(value, list):
        for i, inner in enumerate(value[:4]):
            _leaves(inner, f"{prefix}[{i}]", out, depth + 1)
    elif prefix:
        out.append(prefix)


@router.post(
    "/query",
    summary="Panel data: timeseries, table or data frames",
    **grafana_oa.SIMPLEJSON["query"],
)
@reads_store
def query(request: Request, body: Any = Body(None)) -> JSON:
    """Grafana's query request (``range``, ``intervalMs``, ``maxDataPoints``,
    ``targets``, ``adhocFilters``) → classic SimpleJSON answers
    (``{"target", "datapoints"}``, ``{"type": "table", "columns", "rows"}``)
    or data frames (``{"name", "refId", "fields"}``), per target format.
    Each series is the whole range in at most ``maxDataPoints`` buckets at
    least ``intervalMs`` wide (or its samples, when fewer): every answer
    carries ``meta`` with the bucket width and its ``notices``."""
    doc = _obj(body)
    raw_targets = doc.get("targets")
    if raw_targets is not None and not isinstance(raw_targets, list):
        raise BadRequest("targets must be an array")
    targets = [t for t in raw_targets or [] if isinstance(t, dict) and not t.get("hide") and t.get("target")]
    if len(targets) > _MAX_TARGETS:
        raise BadRequest(f"at most {_MAX_TARGETS} targets per query")
    time = _range(doc)
    max_points = positive_int(_num_text(doc.get("maxDataPoints")), "maxDataPoints", 1000, MAX_POINTS_LIMIT)
    interval_ms = positive_int(_num_text(doc.get("intervalMs")), "intervalMs", None, 10**12)
    filters = _adhoc(doc)
    scope = grafana_scope(request)
    querier = store_of(request).querier()
    out: list[dict] = []
    widths, notices, raw = set(), [], False
    for raw_target in targets:
        budget.checkpoint()  # each target is a step of the request's wall-time budget
        target = Target(raw_target)
        if target.format == "annotations":
            frames_, said = _annotation_frames(querier, scope, target, time, filters)
            out.extend(frames_)
            notices += said
            continue
        query = frames.series_query(
            scope, target.entities, (target.column,), time, max_points, interval_ms, target.agg, target.fill
        )
        drawing = draw(querier, query)
        tracks = [t for t in drawing.tracks if _keep(t.entity_id, t.entity_type, filters)]
        out.extend(_render(target, tracks, several=len(tracks) > 1, meta=_meta(drawing, target)))
        notices += drawing.notices
        if drawing.width is not None:
            widths.add(drawing.width)
        raw = raw or (drawing.width is None and drawing.window is not None)
    width = max(widths) if widths else None
    return JSON(out, headers=drawn_headers(width, raw, notices))


def _meta(drawing: Drawing, target: Target) -> dict:
    """A frame's ``meta``: Grafana shows ``notices`` on the panel; ``custom``
    says the bucket width (``raw``: the samples as stored)."""
    meta: dict[str, Any] = {
        "custom": {"bucket": label(drawing.width) if drawing.width is not None else "raw", "agg": target.agg}
    }
    if drawing.width is not None:
        meta["custom"]["bucketMs"] = drawing.width_ms
    if drawing.notices:
        meta["notices"] = [{"severity": "warning", "text": text} for text in drawing.notices]
    return meta


def _num_text(value: Any) -> str | None:
    if value is None or isinstance(value, bool):
        return None
    return str(value)


def _render(target: Target, tracks: list[Track], several: bool, meta: dict) -> list[dict]:
    name = target.column.name
    lines = [(t, t.lines[name]) for t in tracks if name in t.lines]
    if target.format == "timeseries":
        return [
            {
                "target": f"{frames.short_name(t.entity_id)} {name}" if several or not target.alias else name,
                "refId": target.ref_id,
                "datapoints": [[_number(v), at] for v, at in zip(line.values, line.times, strict=True)],
                "meta": meta,
            }
            for t, line in lines
        ]
    if target.format == "table":
        values = [v for _, line in lines for v in line.values]
        kind = _kind(values)
        rows = sorted(
            (
                [at, t.entity_id, _cell(v, kind)]
                for t, line in lines
                for at, v in zip(line.times, line.values, strict=True)
            ),
            key=lambda r: (r[0], r[1]),
        )
        return [
            {
                "type": "table",
                "refId": target.ref_id,
                "columns": [
                    {"text": "Time", "type": "time"},
                    {"text": "entity", "type": "string"},
                    {"text": name, "type": kind},
                ],
                "rows": rows,
                "meta": meta,
            }
        ]
    out = []
    interval = meta["custom"].get("bucketMs") if target.agg != Mode.MINMAX.value else None
    for t, line in lines:
        kind = _kind(line.values)
        time_field: dict[str, Any] = {"name": "time", "type": "time", "values": line.times}
        if interval:
            time_field["config"] = {"interval": interval}  # Grafana breaks the line where a bucket is missing
        out.append(
            {
                "name": f"{frames.short_name(t.entity_id)} {name}",
                "refId": target.ref_id,
                "meta": meta,
                "fields": [
                    time_field,
                    {
                        "name": name,
                        "type": kind,
                        "values": [_cell(v, kind) for v in line.values],
                        "labels": {"entity": t.entity_id},
                    },
                ],
            }
        )
    return out


def _annotation_frames(
    querier: HistoryReads, scope: Scope, target: Target, time: TimeRange, filters
) -> tuple[list[dict], list[str]]:
    events, notices = _events(querier, scope, target, time, filters, target.equals)
    meta: dict[str, Any] = {}
    if notices:
        meta["notices"] = [{"severity": "warning", "text": text} for text in notices]
    frame: dict[str, Any] = {
        "name": target.column.name,
        "refId": target.ref_id,
        "fields": [
            {"name": "time", "type": "time", "values": [e["time"] for e in events]},
            {"name": "timeEnd", "type": "time", "values": [e["timeEnd"] for e in events]},
            {"name": "title", "type": "string", "values": [e["title"] for e in events]},
            {"name": "text", "type": "string", "values": [e["text"] for e in events]},
            {"name": "tags", "type": "string", "values": [",".join(e["tags"]) for e in events]},
        ],
    }
    if meta:
        frame["meta"] = meta
    return [frame], notices


def _events(
    querier: HistoryReads, scope: Scope, target: Target, time: TimeRange, filters, equals
) -> tuple[list[dict], list[str]]:
    """One event per run of consecutive samples meeting the condition, labelled
    with every value the run went through (``missionState(data) = 1 → 2 → 3``):
    a run of truthy states is several states, not only its first. The newest
    ``_MAX_EVENTS``, with a notice when there were more."""
    matches = frames.condition(None if equals is None else equals if isinstance(equals, str) else frames._text(equals))
    name = target.column.name
    kept = [f for f in filters if f[0] != "type"]
    runs, notices = frames.event_runs(querier, scope, target.entities, (target.column,), time, matches)
    out: list[dict[str, Any]] = []
    for run in runs:
        if kept and not _keep(run.entity_id, "", kept):
            continue
        short = frames.short_name(run.entity_id)
        out.append(
            {
                "time": run.start,
                "timeEnd": run.end,
                "isRegion": run.end > run.start,
                "title": f"{name} on {short}",
                "text": f"{name} = {frames.run_label(list(run.values))} on {run.entity_id}",
                "tags": [short, name],
            }
        )
    out.sort(key=lambda e: (e["time"], e["tags"][0]))
    if len(out) > _MAX_EVENTS:
        notices.append(f"{len(out)} events in the range: only the newest {_MAX_EVENTS} are shown")
    return out[-_MAX_EVENTS:], notices


_MAX_EVENTS = 10_000


@router.post(
    "/annotations",
    name="annotations",
    summary="Annotations (classic SimpleJSON)",
    **grafana_oa.SIMPLEJSON["annotations"],
)
@reads_store
def annotation_events(request: Request, body: Any = Body(None)) -> JSON:
    """``{"range", "annotation": {"query": "<target>[=<JSON value>]", ...}}`` →
    ``[{"annotation", "time", "timeEnd", "isRegion", "title", "text", "tags"}]``
    (times in epoch ms): one per run of samples meeting the condition."""
    doc = _obj(body)
    annotation = _obj(doc.get("annotation"))
    text = _str(annotation.get("query"), "annotation.query").strip()
    if not text:
        return JSON([])
    entity, slash, rest = text.partition("/")  # an id may contain "=": look for it after the id
    path_text, sep, equals = rest.partition("=")
    target = Target({"target": f"{entity}{slash}{path_text}".strip(), "refId": "annotations"})
    scope = grafana_scope(request)
    events, notices = _events(
        store_of(request).querier(), scope, target, _range(doc), [], equals.strip() if sep else None
    )
    head = {k: annotation[k] for k in ("name", "enable", "iconColor", "query") if k in annotation}
    return JSON([{"annotation": head, **event} for event in events], headers=drawn_headers(notices=notices))


@router.post("/tag-keys", summary="Ad hoc filter keys", **grafana_oa.SIMPLEJSON["tag-keys"])
def tag_keys(request: Request, body: Any = Body(None)) -> JSON:
    grafana_scope(request)  # a bad tenant is still a 400
    return JSON(
        [{"type": "string", "text": "entity"}, {"type": "string", "text": "type"}, {"type": "string", "text": "name"}]
    )


@router.post("/tag-values", summary="Ad hoc filter values of one key", **grafana_oa.SIMPLEJSON["tag-values"])
@reads_store
def tag_values(request: Request, body: Any = Body(None)) -> JSON:
    key = _str(_obj(body).get("key"), "key").strip()
    catalog = _catalog(request)
    if key == "entity":
        values = sorted({eid for eid, _ in catalog})
    elif key == "type":
        values = sorted({etype for _, etype in catalog})
    elif key == "name":
        values = sorted({frames.short_name(eid) for eid, _ in catalog})
    else:
        values = []
    return JSON([{"text": v} for v in values])
