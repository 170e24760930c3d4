"""Flat rows for Grafana, computed on top of the history layer.

Every function here builds frozen history queries, runs them through
``history.service`` on the store's querier, and post-processes the per-entity
results in Python into the flat JSON rows dashboards read:

* ``series``: samples of some columns, downsampled to at most ``max_points``
  per entity (avg for numbers, last for states);
* ``latest``: the latest value of each column per entity;
* ``states``: only the rows where a state changes (for state timelines);
* ``events``: runs of samples meeting a condition (annotations);
* ``positions``: time, entity, lat, lon and chosen columns (geomap);
* ``aggregate``: one aggregate per entity (or per period), in SQL.

No SQL is written here and nothing touches storage directly.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import orjson

from tsdb_service.core.query import (
    Aggregation,
    AggrMethod,
    AggrPeriod,
    AggrScope,
    EntityFilter,
    HistoryQuery,
    LastValueQuery,
    Scope,
    Shape,
    TimeRange,
    ValuePath,
)
from tsdb_service.core.timefmt import epoch_ms, iso_z, ms_of, z_of
from tsdb_service.faces.grafana.params import Column
from tsdb_service.geo.encodings import from_geojson, parse_lat_lon
from tsdb_service.history.service import run_history, run_last_values
from tsdb_service.read import HistoryReads

# Raw samples read for one request at most (newest kept): bounds memory and
# time on very long ranges. Downsampling happens after this read.
MAX_RAW_ROWS = 500_000
AGGREGATIONS = ("auto", "avg", "last", "first", "min", "max", "sum", "count")


@dataclass(slots=True)
class EntitySeries:
    """One entity's samples: parallel time and column lists, oldest first."""

    entity_id: str
    entity_type: str
    times: list[int] = field(default_factory=list)  # epoch ms
    columns: dict[str, list] = field(default_factory=dict)


def short_name(entity_id: str) -> str:
    """``urn:ngsiv2:RemoteSensor:Sensor01`` → ``Sensor01``: a readable label."""
    tail = entity_id.rstrip(":").rsplit(":", 1)[-1]
    return tail or entity_id


# --- reading ------------------------------------------------------------------------------


def fetch(
    querier: HistoryReads,
    scope: Scope,
    entities: EntityFilter,
    cols: Sequence[Column],
    time: TimeRange,
    max_rows: int = MAX_RAW_ROWS,
) -> list[EntitySeries]:
    """Raw samples of ``cols`` per entity, through the history service."""
    paths = tuple(dict.fromkeys(col.path for col in cols))
    query = HistoryQuery(
        shape=Shape.ATTRS,
        scope=scope,
        entities=entities,
        attrs=paths,
        time=time,
        last_n=max_rows,
        limit=max_rows,
    )
    out = []
    for ent in run_history(querier, query).entities:
        series = EntitySeries(ent.entity_id, ent.entity_type, [epoch_ms(t) for t in ent.index])
        size = len(series.times)
        for col in cols:
            values = ent.columns.get(col.path.text)
            series.columns[col.name] = list(values) if values is not None else [None] * size
        if any(any(v is not None for v in values) for values in series.columns.values()):
            out.append(series)
    return out


# --- downsampling ---------------------------------------------------------------------------


def _is_number(value) -> bool:
    return type(value) in (int, float)


def column_methods(series: EntitySeries, agg: str) -> dict[str, str]:
    """Per column: ``auto`` is avg where the column holds floats (a measure)
    and last otherwise (integer codes, booleans, text: states)."""
    if agg != "auto":
        return dict.fromkeys(series.columns, agg)
    methods = {}
    for name, values in series.columns.items():
        methods[name] = "avg" if any(type(v) is float for v in values) else "last"
    return methods


def _reduce(method: str, values: list):
    present = [v for v in values if v is not None]
    if method == "count":
        return len(present)
    if not present:
        return None
    if method == "last":
        return present[-1]
    if method == "first":
        return present[0]
    numbers = [v for v in present if _is_number(v)]
    if not numbers:
        return None
    if method == "avg":
        return sum(numbers) / len(numbers)
    if method == "min":
        return min(numbers)
    if method == "max":
        return max(numbers)
    return sum(numbers)  # sum


def bucket_width(times: list[int], max_points: int, interval_ms: int | None, span: tuple[int, int]) -> int:
    """The smallest width (ms, at least ``interval_ms``) giving at most
    ``max_points`` buckets with data."""
    start, end = span
    width = max(interval_ms or 1, math.ceil(max(end - start, 1) / max_points), 1)
    while True:
        buckets, last = 0, None
        for t in times:
            key = t // width
            if key != last:
                buckets += 1
                last = key
                if buckets > max_points:
                    break
        if buckets <= max_points:
            return width
        width *= 2


def downsample(
    series: EntitySeries, max_points: int, interval_ms: int | None, agg: str, span: tuple[int, int] | None = None
) -> EntitySeries:
    """At most ``max_points`` samples: untouched when already that few,
    otherwise one sample per time bucket (stamped at the bucket start)."""
    times = series.times
    if len(times) <= max_points:
        return series
    width = bucket_width(times, max_points, interval_ms, span or (times[0], times[-1]))
    methods = column_methods(series, agg)
    out = EntitySeries(series.entity_id, series.entity_type, [], {name: [] for name in series.columns})
    start = 0
    n = len(times)
    while start < n:
        key = times[start] // width
        stop = start + 1
        while stop < n and times[stop] // width == key:
            stop += 1
        out.times.append(key * width)
        for name, values in series.columns.items():
            out.columns[name].append(_reduce(methods[name], values[start:stop]))
        start = stop
    return out


# --- row shapes ---------------------------------------------------------------------------------


def rows_long(all_series: Sequence[EntitySeries], extra: Callable[[EntitySeries], dict] | None = None) -> list[dict]:
    """``[{"time", "entity", col...}]`` ordered by time, then entity."""
    rows = []
    for series in all_series:
        head = extra(series) if extra else {}
        names = list(series.columns)
        for i, t in enumerate(series.times):
            row = {"time": t, "entity": series.entity_id, **head}
            for name in names:
                row[name] = series.columns[name][i]
            rows.append(row)
    rows.sort(key=lambda r: (r["time"], r["entity"]))
    for row in rows:
        row["time"] = iso_z(row["time"])
    return rows


def rows_wide(all_series: Sequence[EntitySeries]) -> list[dict]:
    """One row per time, one column per (entity, column): ``"Sensor01 temperature"``.
    Entities are named by the last part of their id unless two would clash."""
    shorts = [short_name(s.entity_id) for s in all_series]
    clash = len(set(shorts)) != len(shorts)
    by_time: dict[int, dict] = {}
    names: list[str] = []
    for series, short in zip(all_series, shorts, strict=True):
        label = series.entity_id if clash else short
        for name, values in series.columns.items():
            column = f"{label} {name}"
            names.append(column)
            for t, value in zip(series.times, values, strict=True):
                by_time.setdefault(t, {})[column] = value
    rows = []
    for t in sorted(by_time):
        cells = by_time[t]
        rows.append({"time": iso_z(t), **{name: cells.get(name) for name in names}})
    return rows


# --- endpoints' computations ------------------------------------------------------------------------


def series_rows(
    querier: HistoryReads,
    scope: Scope,
    entities: EntityFilter,
    cols: Sequence[Column],
    time: TimeRange,
    *,
    max_points: int,
    interval_ms: int | None,
    agg: str,
    wide: bool = False,
) -> list[dict]:
    fetched = fetch(querier, scope, entities, cols, time)
    span = _span(time)
    sampled = [downsample(s, max_points, interval_ms, agg, _fill(span, s)) for s in fetched]
    return rows_wide(sampled) if wide else rows_long(sampled)


def _span(time: TimeRange) -> tuple[int | None, int | None]:
    return ms_of(time.start), ms_of(time.end)


def _fill(span: tuple[int | None, int | None], series: EntitySeries) -> tuple[int, int] | None:
    if not series.times:
        return None
    start, end = span
    return (series.times[0] if start is None else start, series.times[-1] if end is None else end)


def state_rows(
    querier: HistoryReads,
    scope: Scope,
    entities: EntityFilter,
    cols: Sequence[Column],
    time: TimeRange,
    *,
    max_points: int,
) -> list[dict]:
    """Rows where any column's value changes (missing values carry the
    previous one), plus each entity's last sample, so a state timeline ends
    where the data ends."""
    out = []
    for series in fetch(querier, scope, entities, cols, time):
        changed = _changes(series)
        if len(changed.times) > max_points:
            changed = _changes(downsample(changed, max_points, None, "last", _fill(_span(time), changed)))
        out.append(changed)
    return rows_long(out)


def _changes(series: EntitySeries) -> EntitySeries:
    names = list(series.columns)
    out = EntitySeries(series.entity_id, series.entity_type, [], {name: [] for name in names})
    current: list = [None] * len(names)
    previous: list | None = None
    last_index = len(series.times) - 1
    for i, t in enumerate(series.times):
        for j, name in enumerate(names):
            value = series.columns[name][i]
            if value is not None:
                current[j] = value
        if previous is None or current != previous or i == last_index:
            if previous is not None and current == previous and out.times and out.times[-1] == t:
                continue
            out.times.append(t)
            for j, name in enumerate(names):
                out.columns[name].append(current[j])
            previous = list(current)
    return out


def condition(equals: str | None) -> Callable[[object], bool]:
    """``equals`` absent: truthy values (true, non-zero); else equality with
    the JSON value given (``true``, ``1``, ``"open"``) or the text."""
    if equals is None or equals == "":
        return lambda v: v is not None and v is not False and v != 0 and v != ""
    try:
        wanted = orjson.loads(equals)
    except orjson.JSONDecodeError:
        wanted = equals
    if type(wanted) is bool:
        return lambda v: v is wanted
    if _is_number(wanted):
        return lambda v: _is_number(v) and v == wanted
    return lambda v: v == wanted


def event_rows(
    querier: HistoryReads,
    scope: Scope,
    entities: EntityFilter,
    cols: Sequence[Column],
    time: TimeRange,
    *,
    matches: Callable[[object], bool],
    text: str | None,
    limit: int,
) -> list[dict]:
    """Annotations: one per run of consecutive samples meeting the condition,
    from its first to its last matching sample, labelled with every value the
    run went through (as the SimpleJSON annotations are)."""
    events = []
    for series in fetch(querier, scope, entities, cols, time):
        for name, values in series.columns.items():
            for first, last in runs(values, matches):
                label = run_label(values[first : last + 1])
                events.append(_event(series, name, label, series.times[first], series.times[last], text))
    events.sort(key=lambda e: (e["time"], e["entity"], e["title"]))
    events = events[-limit:]
    for event in events:
        event["time"], event["timeEnd"] = iso_z(event["time"]), iso_z(event["timeEnd"])
    return events


def _event(series: EntitySeries, name: str, label: str, start: int, end: int, text: str | None) -> dict:
    short = short_name(series.entity_id)
    return {
        "time": start,
        "timeEnd": end,
        "entity": series.entity_id,
        "title": f"{name} on {short}",
        "text": text or f"{name} = {label} on {series.entity_id}",
        "tags": f"{short},{name}",
    }


MAX_LABEL_VALUES = 12


def runs(values: list, matches: Callable[[object], bool]) -> list[tuple[int, int]]:
    """(first, last) index of each run of consecutive values meeting ``matches``."""
    found, first = [], None
    for i, value in enumerate(values):
        if value is not None and matches(value):
            first = i if first is None else first
        elif first is not None:
            found.append((first, i - 1))
            first = None
    if first is not None:
        found.append((first, len(values) - 1))
    return found


def run_label(values: list) -> str:
    """The values a run went through, each change once: ``1 → 2 → 3``. A run
    of truthy states is several states, not only its first."""
    changes = [v for i, v in enumerate(values) if i == 0 or v != values[i - 1]]
    shown = " → ".join(_text(v) for v in changes[:MAX_LABEL_VALUES])
    return shown + (" → …" if len(changes) > MAX_LABEL_VALUES else "")


def _text(value) -> str:
    if isinstance(value, str):
        return value
    return orjson.dumps(value).decode()


def lon_lat(value) -> tuple[float, float] | None:
    """A stored location (GeoJSON, ``"lat, lon"``) → (lon, lat)."""
    if type(value) is dict:
        geometry = from_geojson(value)
        return None if geometry is None else (geometry.lon, geometry.lat)
    if type(value) is str:
        position = parse_lat_lon(value)
        if position is None:
            try:
                decoded = orjson.loads(value)
            except orjson.JSONDecodeError:
                return None
            return lon_lat(decoded) if type(decoded) is dict else None
        return position[0], position[1]
    return None


def position_rows(
    querier: HistoryReads,
    scope: Scope,
    entities: EntityFilter,
    location: ValuePath,
    cols: Sequence[Column],
    time: TimeRange,
    *,
    latest: bool,
    max_points: int,
    geo=None,
) -> list[dict]:
    """``[{"time", "entity", "type", "name", "lat", "lon", col...}]``: one row per
    located sample (or only each entity's latest with ``latest``). ``geo`` is
    a ``GeoFilter``; a position is kept when its point matches it."""
    loc = Column("__location__", location)
    if latest:
        return _latest_positions(querier, scope, entities, loc, cols, geo)
    rows = []
    for series in fetch(querier, scope, entities, (loc, *cols), time):
        located = EntitySeries(
            series.entity_id, series.entity_type, [], {name: [] for name in ("lat", "lon", *(c.name for c in cols))}
        )
        for i, t in enumerate(series.times):
            point = lon_lat(series.columns[loc.name][i])
            if point is None or (geo is not None and not _geo_ok(geo, point)):
                continue
            located.times.append(t)
            located.columns["lat"].append(point[1])
            located.columns["lon"].append(point[0])
            for col in cols:
                located.columns[col.name].append(series.columns[col.name][i])
        if located.times:
            rows.append(downsample(located, max_points, None, "last", None))
    return rows_long(rows, extra=lambda s: {"type": s.entity_type, "name": short_name(s.entity_id)})


def _geo_ok(geo, point: tuple[float, float]) -> bool:
    return geo.matches({"type": "Point", "coordinates": [point[0], point[1]]})


def _latest_positions(
    querier: HistoryReads, scope: Scope, entities: EntityFilter, loc: Column, cols: Sequence[Column], geo
) -> list[dict]:
    rows = []
    for item in latest_rows(querier, scope, entities, (loc, *cols)):
        point = lon_lat(item.pop(loc.name))
        if point is None or (geo is not None and not _geo_ok(geo, point)):
            continue
        head = {
            "time": item.pop("time"),
            "entity": item.pop("entity"),
            "type": item.pop("type"),
            "name": item.pop("name"),
        }
        rows.append({**head, "lat": point[1], "lon": point[0], **item})
    rows.sort(key=lambda r: r["entity"])
    return rows


def latest_rows(querier: HistoryReads, scope: Scope, entities: EntityFilter, cols: Sequence[Column]) -> list[dict]:
    """``[{"entity", "type", "name", "time", col...}]``: the latest value of
    each column per entity; ``time`` is the newest of those samples."""
    paths = tuple(dict.fromkeys(col.path for col in cols))
    found = run_last_values(querier, LastValueQuery(scope, (entities,), paths))
    rows = []
    for ent in found:
        row = {
            "entity": ent["id"],
            "type": ent["type"],
            "name": short_name(ent["id"]),
            "time": z_of(ent["dateModified"]["value"]),
        }
        for col in cols:
            cell = ent.get(col.path.text)
            row[col.name] = None if cell is None else cell["value"]
        if any(row[col.name] is not None for col in cols):
            rows.append(row)
    return rows


def aggregate_rows(
    querier: HistoryReads,
    scope: Scope,
    entities: EntityFilter,
    cols: Sequence[Column],
    time: TimeRange,
    *,
    method: AggrMethod,
    period: AggrPeriod | None,
    limit: int,
) -> list[dict]:
    """One row per entity (and period): ``[{"entity", "type", "name",
    ("time",) col...}]``, aggregated in SQL by the history layer."""
    aggregation = Aggregation(method, period, AggrScope.ENTITY)
    paths = tuple(dict.fromkeys(col.path for col in cols))
    query = HistoryQuery(
        shape=Shape.ATTRS, scope=scope, entities=entities, attrs=paths, time=time, limit=limit, aggregation=aggregation
    )
    rows = []
    for ent in run_history(querier, query).entities:
        head = {"entity": ent.entity_id, "type": ent.entity_type, "name": short_name(ent.entity_id)}
        count = max((len(v) for v in ent.columns.values()), default=0)
        for i in range(count):
            row: dict[str, object] = dict(head)
            if period:
                row["time"] = z_of(ent.index[i]) if i < len(ent.index) else None
            for col in cols:
                values = ent.columns.get(col.path.text) or []
                row[col.name] = values[i] if i < len(values) else None
            rows.append(row)
    return rows
