"""Flat rows for Grafana, computed on top of the history layer.

Every function here builds frozen history queries, runs them through
``history`` on the store's querier, and shapes the per-entity results into
the flat JSON rows dashboards read. What draws a window reads time buckets
the database computed (``history.drawing``), never the window's samples:

* ``series``: columns over a window in a point budget (``history.drawing``:
  buckets in a ``Mode``, gaps as nulls or filled, raw samples when they fit);
* ``latest``: the latest value of each column per entity;
* ``states``: only the rows where a state changes (for state timelines),
  from the database's transitions;
* ``events``: runs of samples meeting a condition (annotations), from the
  same transitions;
* ``positions``: time, entity, lat, lon and chosen columns (geomap): the
  samples when at most ``max_points`` a series, else the last position of
  each bucket;
* ``aggregate``: one aggregate per entity (or per period), in SQL.

Each answer that draws comes as a ``Shown``: its rows, the bucket width
(None: raw samples) and the notices saying what a cap left out (the routes
put both in headers). No SQL is written here and nothing touches storage
directly.
"""

from __future__ import annotations

import bisect
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from datetime import timedelta

import orjson

from tsdb_service.core import budget
from tsdb_service.core.buckets import choose_width
from tsdb_service.core.query import (
    Aggregation,
    AggrMethod,
    AggrPeriod,
    AggrScope,
    EntityFilter,
    HistoryQuery,
    LastValueQuery,
    Scope,
    SeriesRef,
    Shape,
    TimeRange,
    ValuePath,
)
from tsdb_service.core.timefmt import iso_z_ms, ms_of_iso, z_of
from tsdb_service.faces.grafana.params import Column
from tsdb_service.geo.encodings import from_geojson, parse_lat_lon
from tsdb_service.history.drawing import (
    Drawing,
    DrawQuery,
    Fill,
    Line,
    Mode,
    Track,
    changes_lines,
    draw,
    extracted,
    path_reads,
    resolve_window,
    window_range,
)
from tsdb_service.history.service import run_history, run_last_values
from tsdb_service.history.valuepath import extract
from tsdb_service.http.responses import drawn_headers
from tsdb_service.read import HistoryReads
from tsdb_service.read.buckets import BucketRead
from tsdb_service.read.requests import SamplesIn, SeriesSelect

AGGREGATIONS = tuple(mode.value for mode in Mode)
FILLS = tuple(fill.value for fill in Fill)
# Transitions one events request reads per column, the newest kept: past it
# the answer says which events were left out.
EVENT_CHANGES = 100_000
# GeoJSON point coordinates: the numbers a thinned track reads.
_LON, _LAT = ("coordinates", 0), ("coordinates", 1)


@dataclass(slots=True)
class Shown:
    """What an endpoint answers: rows, the bucket width (None: raw samples or
    nothing drawn in buckets) and what was left out, in words."""

    rows: list[dict]
    width: timedelta | None = None
    notices: list[str] = field(default_factory=list)
    raw: bool = False  # the samples as stored (no bucket)

    def headers(self) -> dict[str, str]:
        return drawn_headers(self.width, self.raw, self.notices)


def short_name(entity_id: str) -> str:
    """``urn:ngsiv2:RemoteSensor:Sensor01`` → ``Sensor01``: a readable label."""
    tail = entity_id.rstrip(":").rsplit(":", 1)[-1]
    return tail or entity_id


# --- row shapes ---------------------------------------------------------------------------------


def rows_long(tracks: Sequence[Track], extra: Callable[[Track], dict] | None = None) -> list[dict]:
    """``[{"time", "entity", col...}]`` ordered by time, then entity. A row
    holds the columns with a point at its time (a null: a gap); a column
    without a point there is left out."""
    rows: list[dict] = []
    for track in tracks:
        head = extra(track) if extra else {}
        cells: dict[tuple[int, int], dict] = {}
        for name, line in track.lines.items():
            for key, value in zip(_keys(line.times), line.values, strict=True):
                row = cells.get(key)
                if row is None:
                    row = cells[key] = {"time": key[0], "entity": track.entity_id, **head}
                row[name] = value
        rows.extend(cells.values())
    rows.sort(key=lambda r: (r["time"], r["entity"]))
    for row in rows:
        row["time"] = iso_z_ms(row["time"])
    return rows


def rows_wide(tracks: Sequence[Track]) -> list[dict]:
    """One row per time, one column per (entity, column): ``"Sensor01 temperature"``.
    Entities are named by the last part of their id unless two would clash."""
    shorts = [short_name(t.entity_id) for t in tracks]
    clash = len(set(shorts)) != len(shorts)
    by_time: dict[tuple[int, int], dict] = {}
    for track, short in zip(tracks, shorts, strict=True):
        label = track.entity_id if clash else short
        for name, line in track.lines.items():
            column = f"{label} {name}"
            for key, value in zip(_keys(line.times), line.values, strict=True):
                by_time.setdefault(key, {})[column] = value
    return [{"time": iso_z_ms(key[0]), **by_time[key]} for key in sorted(by_time)]


def _keys(times: list[int]) -> list[tuple[int, int]]:
    """(time, how many points of the line came before at that time): two
    samples of one instant are two rows, never one written over the other."""
    keys: list[tuple[int, int]] = []
    for i, t in enumerate(times):
        keys.append((t, keys[-1][1] + 1 if i and times[i - 1] == t else 0))
    return keys


# --- endpoints' computations ------------------------------------------------------------------------


def series_rows(querier: HistoryReads, query: DrawQuery, wide: bool = False) -> Shown:
    """``series``: ``query`` drawn (``history.drawing``) as long or wide rows."""
    drawing = draw(querier, query)
    rows = rows_wide(drawing.tracks) if wide else rows_long(drawing.tracks)
    return Shown(rows, drawing.width, drawing.notices, raw=drawing.width is None and drawing.window is not None)


def series_query(
    scope: Scope,
    entities: EntityFilter,
    cols: Sequence[Column],
    time: TimeRange,
    max_points: int,
    interval_ms: int | None,
    agg: str,
    fill: str,
) -> DrawQuery:
    floor = None if interval_ms is None else timedelta(milliseconds=interval_ms)
    return DrawQuery(scope, entities, tuple(cols), time, max_points, floor, Mode(agg), Fill(fill))


def _value_lines(
    querier: HistoryReads, refs: list[SeriesRef], cols: Sequence[Column], window: tuple[int, int], limit: int
) -> tuple[dict[tuple[str, str], dict[str, Line]], list[str]]:
    """Per entity, per column: the values at their transitions (and at the
    series' last sample); the notices of transitions left out."""
    by_sid = {r.sid: r for r in refs}
    out: dict[tuple[str, str], dict[str, Line]] = {}
    notices = []
    for read in path_reads(cols, refs):
        entities = len({by_sid[sid].entity_id for sid in read.sids})
        lines, notice = changes_lines(querier, read, window, limit * entities)
        if notice:
            notices.append(notice)
        for sid, line in lines.items():
            ref = by_sid[sid]
            for col in cols:
                if col.path.attr == ref.attr and col.path.steps == read.steps:
                    out.setdefault((ref.entity_type, ref.entity_id), {})[col.name] = extracted(line, col.path)
    return out, notices


def _extracted_value(value, path: ValuePath):
    return extract(value, path.steps) if path.steps else value


def _selected(querier: HistoryReads, scope: Scope, entities: EntityFilter, cols: Sequence[Column]) -> list[SeriesRef]:
    return querier.series(SeriesSelect(scope, entities, {c.path.attr for c in cols}))


def state_rows(
    querier: HistoryReads,
    scope: Scope,
    entities: EntityFilter,
    cols: Sequence[Column],
    time: TimeRange,
    *,
    max_points: int,
) -> Shown:
    """Rows where any column's value changes (a column that did not change
    carries its value), plus each entity's last sample, so a state timeline
    ends where the data ends. Every transition (never averaged): at most
    ``max_points`` per entity and column, the newest, with a notice."""
    refs = _selected(querier, scope, entities, cols)
    window = resolve_window(querier, [r.sid for r in refs], time) if refs else None
    if window is None:
        return Shown([])
    by_entity, notices = _value_lines(querier, refs, cols, window, max_points)
    rows: list[dict] = []
    for (_etype, eid), lines in by_entity.items():
        names = [c.name for c in cols if c.name in lines]
        times = sorted({t for name in names for t in lines[name].times})
        at = dict.fromkeys(names, 0)
        current: dict[str, object] = dict.fromkeys(names)
        for t in times:
            for name in names:
                line = lines[name]
                while at[name] < len(line.times) and line.times[at[name]] <= t:
                    current[name] = line.values[at[name]]
                    at[name] += 1
            rows.append({"time": t, "entity": eid, **current})
    rows.sort(key=lambda r: (r["time"], r["entity"]))
    for row in rows:
        row["time"] = iso_z_ms(row["time"])
    return Shown(rows, None, notices)


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


def _is_number(value) -> bool:
    return type(value) in (int, float)


@dataclass(frozen=True, slots=True)
class Run:
    """A run of samples of one column meeting a condition: from its first to
    its last sample (epoch ms), through ``values`` (each change once)."""

    entity_id: str
    column: str
    start: int
    end: int
    values: tuple


def event_runs(
    querier: HistoryReads,
    scope: Scope,
    entities: EntityFilter,
    cols: Sequence[Column],
    time: TimeRange,
    matches: Callable[[object], bool],
) -> tuple[list[Run], list[str]]:
    """The runs of every column, from the database's transitions: a run
    starts at a transition to a matching value, goes through the matching
    ones after it and ends at the last sample before the first that does not
    match (``StateChange.before``), or at the series' last sample. When older
    transitions were left out (``EVENT_CHANGES``), runs are answered from the
    first one that surely started in what was read, and a notice says so."""
    refs = _selected(querier, scope, entities, cols)
    window = resolve_window(querier, [r.sid for r in refs], time) if refs else None
    if window is None:
        return [], []
    from tsdb_service.history.drawing import change_value
    from tsdb_service.read.buckets import ChangesRead

    by_sid = {r.sid: r for r in refs}
    runs: list[Run] = []
    notices = []
    span = window_range(window)
    for read in path_reads(cols, refs):
        steps, sids = read.steps, list(read.sids)
        page = querier.state_changes(ChangesRead(sids, span, EVENT_CHANGES, steps))
        budget.charge_rows(len(page.changes))
        last = dict(querier.latest_index(SamplesIn(sids, span)))
        if page.truncated and page.changes:
            notices.append(
                f"more than {EVENT_CHANGES} state changes in the window: events are shown from "
                f"{iso_z_ms(page.changes[0].time // 1000)} on; narrow the window to see the older ones"
            )
        per_sid: dict[int, list] = {}
        for change in page.changes:
            per_sid.setdefault(change.sid, []).append(change)
        for sid, changes in per_sid.items():
            ref = by_sid[sid]
            for col in cols:
                if col.path.attr != ref.attr or col.path.steps != steps:
                    continue
                values = [_extracted_value(change_value(c), col.path) for c in changes]
                skip_first = page.truncated  # the first kept run may have started before
                end_of = ms_of_iso(last[sid]) if sid in last else changes[-1].time // 1000
                runs += _runs(ref.entity_id, col.name, changes, values, matches, end_of, skip_first)
    return runs, notices


def _runs(eid: str, name: str, changes, values: list, matches, end_of: int, skip_first: bool) -> list[Run]:
    out = []
    first = None
    for i, value in enumerate(values):
        ok = value is not None and matches(value)
        if ok and first is None:
            first = i
        elif not ok and first is not None:
            out.append(_run(eid, name, changes, values, first, i))
            first = None
    if first is not None:
        out.append(Run(eid, name, changes[first].time // 1000, end_of, _distinct(values[first:])))
    if skip_first and out and out[0].start == changes[0].time // 1000:
        out = out[1:]
    return out


def _run(eid: str, name: str, changes, values: list, first: int, stop: int) -> Run:
    end = changes[stop].before
    return Run(eid, name, changes[first].time // 1000, end // 1000, _distinct(values[first:stop]))


def _distinct(values: list) -> tuple:
    return tuple(v for i, v in enumerate(values) if i == 0 or v != values[i - 1])


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
) -> Shown:
    """Annotations: one per run of consecutive samples meeting the condition,
    from its first to its last matching sample, labelled with every value the
    run went through (as the SimpleJSON annotations are). The newest
    ``limit``, with a notice when there were more."""
    runs, notices = event_runs(querier, scope, entities, cols, time, matches)
    events = [_event(run, text) for run in runs]
    events.sort(key=lambda e: (e["time"], e["entity"], e["title"]))
    if len(events) > limit:
        notices.append(f"{len(events)} events in the window: only the newest {limit} are shown (limit)")
        events = events[-limit:]
    for event in events:
        event["time"], event["timeEnd"] = iso_z_ms(event["time"]), iso_z_ms(event["timeEnd"])
    return Shown(events, None, notices)


def _event(run: Run, text: str | None) -> dict:
    short = short_name(run.entity_id)
    return {
        "time": run.start,
        "timeEnd": run.end,
        "entity": run.entity_id,
        "title": f"{run.column} on {short}",
        "text": text or f"{run.column} = {run_label(list(run.values))} on {run.entity_id}",
        "tags": f"{short},{run.column}",
    }


MAX_LABEL_VALUES = 12


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
) -> Shown:
    """``[{"time", "entity", "type", "name", "lat", "lon", col...}]``: one row per
    located sample while no entity has more than ``max_points`` in the
    window, else the last position of each time bucket (``max_points``
    buckets), with its columns' last values in that bucket; or only each
    entity's latest with ``latest``. ``geo`` is a ``GeoFilter``; a position
    is kept when its point matches it."""
    loc = Column("__location__", location)
    if latest:
        return Shown(_latest_positions(querier, scope, entities, loc, cols, geo))
    loc_refs = querier.series(SeriesSelect(scope, entities, {location.attr}))
    if not loc_refs:
        return Shown([])
    entities_n = len({(r.entity_type, r.entity_id) for r in loc_refs})
    cap = max_points * entities_n
    if querier.count(SamplesIn([r.sid for r in loc_refs], time)) <= cap:
        tracks = _raw_positions(querier, scope, entities, loc, cols, time, max_points, cap, geo)
        if tracks is not None:
            return Shown(rows_long(tracks, extra=_place), raw=True)
    return _thinned_positions(querier, scope, entities, loc, loc_refs, cols, time, max_points, geo)


def _place(track: Track) -> dict:
    return {"type": track.entity_type, "name": short_name(track.entity_id)}


def _raw_positions(
    querier: HistoryReads,
    scope: Scope,
    entities: EntityFilter,
    loc: Column,
    cols: Sequence[Column],
    time: TimeRange,
    max_points: int,
    cap: int,
    geo,
) -> list[Track] | None:
    """Every located sample (no entity above ``max_points``), or None."""
    paths = tuple(dict.fromkeys(c.path for c in (loc, *cols)))
    query = HistoryQuery(shape=Shape.ATTRS, scope=scope, entities=entities, attrs=paths, time=time, limit=cap + 1)
    tracks = []
    for ent in run_history(querier, query).entities:
        located = Track(
            ent.entity_id, ent.entity_type, {name: Line() for name in ("lat", "lon", *(c.name for c in cols))}
        )
        where = ent.columns.get(loc.path.text) or []
        for i, iso in enumerate(ent.index):
            point = lon_lat(where[i]) if i < len(where) else None
            if point is None or (geo is not None and not _geo_ok(geo, point)):
                continue
            t = ms_of_iso(iso)
            located.lines["lat"].add(t, point[1])
            located.lines["lon"].add(t, point[0])
            for col in cols:
                values = ent.columns.get(col.path.text)
                located.lines[col.name].add(t, values[i] if values is not None else None)
        if len(located.lines["lat"].times) > max_points:
            return None
        if located.lines["lat"].times:
            tracks.append(located)
    return tracks


def _thinned_positions(
    querier: HistoryReads,
    scope: Scope,
    entities: EntityFilter,
    loc: Column,
    loc_refs: list[SeriesRef],
    cols: Sequence[Column],
    time: TimeRange,
    max_points: int,
    geo,
) -> Shown:
    """The last GeoJSON point of each bucket (its coordinates' last numbers,
    the same sample), with each column's value then: the bucket's last number,
    or the state in force (transitions)."""
    sids = [r.sid for r in loc_refs]
    window = resolve_window(querier, sids, time)
    if window is None:
        return Shown([])
    span = window_range(window)
    width = choose_width(timedelta(microseconds=window[1] - window[0]), max_points)
    lons = {(r.sid, r.start): r for r in querier.buckets(BucketRead(sids, span, width, _LON, False))}
    lats = {(r.sid, r.start): r for r in querier.buckets(BucketRead(sids, span, width, _LAT, False))}
    budget.charge_rows(len(lons) + len(lats))
    extra = _column_lines(querier, scope, entities, cols, span, max_points, width)
    by_sid = {r.sid: r for r in loc_refs}
    tracks: dict[tuple[str, str], Track] = {}
    for key, lon in lons.items():
        lat = lats.get(key)
        if lat is None or lat.last_t != lon.last_t:
            continue
        point = (lon.last, lat.last)
        if geo is not None and not _geo_ok(geo, point):
            continue
        ref = by_sid[key[0]]
        track = tracks.get((ref.entity_type, ref.entity_id))
        if track is None:
            names = ("lat", "lon", *(c.name for c in cols))
            track = tracks[(ref.entity_type, ref.entity_id)] = Track(
                ref.entity_id, ref.entity_type, {name: Line() for name in names}
            )
        t = lon.last_t // 1000
        track.lines["lat"].add(t, point[1])
        track.lines["lon"].add(t, point[0])
        lines = extra.get((ref.entity_type, ref.entity_id), {})
        for col in cols:
            track.lines[col.name].add(t, _value_at(lines.get(col.name), t))
    notices = []
    placed = {key[0] for key in lons}
    unplaced = sorted({by_sid[s].entity_id for s in sids if s not in placed})
    if unplaced and querier.count(SamplesIn([s for s in sids if s not in placed], span)):
        notices.append(
            f"positions of {', '.join(unplaced[:5])}{' ...' if len(unplaced) > 5 else ''} are not GeoJSON "
            f"points and cannot be thinned: narrow the window to at most {max_points} positions to see them"
        )
    ordered = [tracks[k] for k in sorted(tracks, key=lambda k: (k[1], k[0]))]
    for track in ordered:
        _sort_track(track)
    return Shown(rows_long(ordered, extra=_place), width, notices)


def _sort_track(track: Track) -> None:
    order = sorted(range(len(track.lines["lat"].times)), key=track.lines["lat"].times.__getitem__)
    for line in track.lines.values():
        line.times[:] = [line.times[i] for i in order]
        line.values[:] = [line.values[i] for i in order]


def _column_lines(
    querier: HistoryReads,
    scope: Scope,
    entities: EntityFilter,
    cols: Sequence[Column],
    span: TimeRange,
    max_points: int,
    width: timedelta,
) -> dict[tuple[str, str], dict[str, Line]]:
    """Each column's last value per bucket of ``width`` (states: their transitions)."""
    if not cols:
        return {}
    query = DrawQuery(scope, entities, tuple(cols), span, max_points, width, Mode.LAST, Fill.NONE, raw=False)
    drawing: Drawing = draw(querier, query)
    return {(t.entity_type, t.entity_id): t.lines for t in drawing.tracks}


def _value_at(line: Line | None, t: int):
    """The line's value in force at ``t`` (epoch ms): its last point at or before."""
    if line is None:
        return None
    at = bisect.bisect_right(line.times, t) - 1
    return line.values[at] if at >= 0 else None


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
) -> Shown:
    """One row per entity (and period): ``[{"entity", "type", "name",
    ("time",) col...}]``, aggregated in SQL by the history layer. At most
    ``limit`` rows (entities, then periods, in order), with a notice when
    there were more."""
    aggregation = Aggregation(method, period, AggrScope.ENTITY)
    paths = tuple(dict.fromkeys(col.path for col in cols))
    query = HistoryQuery(
        shape=Shape.ATTRS,
        scope=scope,
        entities=entities,
        attrs=paths,
        time=time,
        limit=limit + 1,
        aggregation=aggregation,
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
    notices = []
    if len(rows) > limit:
        notices.append(f"more than {limit} aggregate rows: the first {limit} are shown (limit)")
        rows = rows[:limit]
    return Shown(rows, None, notices)
