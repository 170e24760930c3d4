"""Drawing long windows: what every face that draws reads.

Grafana's Infinity and SimpleJSON endpoints and the explorer draw a window of
any length in a budget of points per series. The database computes time
buckets (``read.buckets``) and this module turns them into lines:

    drawing = draw(querier, DrawQuery(scope, entities, columns, time, points=1000))
    drawing.tracks     # per entity, per column: times (epoch ms) and values
    drawing.width      # the bucket width (None: raw samples, drawn as stored)
    drawing.notices    # what was left out, said in words (empty: nothing)

Invariants:

* the whole window is answered: buckets of ``core.buckets.choose_width``
  (round widths aligned to the epoch) from its first to its last; no row
  cap shortens it;
* a point stands for one bucket, stamped at the start of the bucket's part
  inside the window, valued by ``Mode`` (``auto``: the average where the
  series holds fractions, the last value where it holds integers only, so
  integer codes are never averaged); the min-max mode draws up to four per
  bucket, the first, the minimum, the maximum and the last at their own
  times, so a one-sample spike of a month shows at 1,000 points;
* a bucket without a sample is a gap: ``Fill.NONE`` marks each run of empty
  buckets between two points with one null (a chart breaks its line there);
  ``null`` gives every empty bucket a null, ``previous`` the value before
  it, ``linear`` the straight line between its neighbours;
* raw samples are drawn as stored when the window holds at most ``points``
  samples a series (``count_up_to``: never more read to know), no column of
  an entity has more than ``points`` of them, and the mode keeps values
  (not ``count``, ``sum``);
* a series without a number in the window (texts, booleans, JSON) is drawn
  from its transitions (``BucketReader.state_changes``) and its last sample,
  never averaged; at most ``changes`` transitions per read, the newest, and a
  notice says when older ones were left out.
"""

from __future__ import annotations

import bisect
from collections.abc import Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime, timedelta
from enum import Enum

from tsdb_service.core import budget
from tsdb_service.core.buckets import bucket_count, bucket_start, choose_width, epoch_micros
from tsdb_service.core.model import Kind
from tsdb_service.core.query import EntityFilter, Scope, SeriesRef, TimeRange, ValuePath
from tsdb_service.core.timefmt import ms_of_iso
from tsdb_service.history.service import decode
from tsdb_service.history.valuepath import extract
from tsdb_service.read import HistoryReads
from tsdb_service.read.buckets import BucketRead, BucketRow, ChangesRead, StateChange
from tsdb_service.read.requests import SamplesIn, SeriesSelect

_US = timedelta(microseconds=1)
_EPOCH = datetime(1970, 1, 1, tzinfo=UTC)


class Mode(str, Enum):
    """What one point of a bucket shows."""

    AUTO = "auto"
    AVG = "avg"
    MIN = "min"
    MAX = "max"
    FIRST = "first"
    LAST = "last"
    SUM = "sum"
    COUNT = "count"
    MINMAX = "minmax"


# Modes a bucket of one sample shows as that sample: raw samples can stand for them.
VALUE_MODES = frozenset({Mode.AUTO, Mode.AVG, Mode.MIN, Mode.MAX, Mode.FIRST, Mode.LAST, Mode.MINMAX})


class Fill(str, Enum):
    """What an empty bucket shows (as the time-series databases name it)."""

    NONE = "none"
    NULL = "null"
    PREVIOUS = "previous"
    LINEAR = "linear"


@dataclass(frozen=True, slots=True)
class Column:
    """One drawn column: a value path and the name it is drawn under."""

    name: str
    path: ValuePath


@dataclass(frozen=True, slots=True)
class DrawQuery:
    """``columns`` of the entities ``entities`` in ``scope`` over ``time`` (an
    open end: the data's), at most ``points`` buckets per series, none
    narrower than ``floor``. ``changes``: transitions kept per column read of
    the series without numbers (default ``points`` per series)."""

    scope: Scope
    entities: EntityFilter
    columns: tuple[Column, ...]
    time: TimeRange
    points: int = 1000
    floor: timedelta | None = None
    mode: Mode = Mode.AUTO
    fill: Fill = Fill.NONE
    changes: int | None = None
    raw: bool = True  # raw samples may answer when they fit (``VALUE_MODES``)


@dataclass(slots=True)
class Line:
    """One column of one entity: times (epoch ms, ascending) and values; a
    None value is a gap (or a null the entity sent)."""

    times: list[int] = field(default_factory=list)
    values: list = field(default_factory=list)

    def add(self, t: int, value) -> None:
        self.times.append(t)
        self.values.append(value)


@dataclass(slots=True)
class Track:
    entity_id: str
    entity_type: str
    lines: dict[str, Line] = field(default_factory=dict)


@dataclass(slots=True)
class Drawing:
    tracks: list[Track]
    window: tuple[int, int] | None = None  # epoch µs, inclusive (None: no data)
    width: timedelta | None = None  # None: raw samples
    notices: list[str] = field(default_factory=list)

    @property
    def width_ms(self) -> int | None:
        return None if self.width is None else self.width // timedelta(milliseconds=1)


@dataclass(frozen=True, slots=True)
class PathRead:
    """One ``BucketRead``/``ChangesRead``: the series of the columns sharing a path's steps."""

    steps: tuple[str | int, ...]
    sids: tuple[int, ...]


def draw(querier: HistoryReads, q: DrawQuery) -> Drawing:
    refs = querier.series(SeriesSelect(q.scope, q.entities, {c.path.attr for c in q.columns}))
    if not refs:
        return Drawing([])
    window = resolve_window(querier, [r.sid for r in refs], q.time)
    if window is None:
        return Drawing([])
    width = choose_width(_span(window), q.points, q.floor)
    reads = path_reads(q.columns, refs)
    if q.raw and q.mode in VALUE_MODES:
        sids = sorted({sid for read in reads for sid in read.sids})
        most = q.points * len(sids)
        if querier.count_up_to(SamplesIn(sids, window_range(window)), most + 1) <= most:
            charged = budget.mark()
            raw = _raw(querier, q, refs, window)
            if raw is not None:
                return raw
            budget.rewind(charged)  # one column held too many: the buckets answer instead
    rows: dict[tuple[tuple[str | int, ...], int], list[BucketRow]] = {}  # (steps, sid) -> buckets
    for read in reads:
        found = querier.buckets(BucketRead(read.sids, window_range(window), width, read.steps, q.mode is Mode.MINMAX))
        budget.charge_rows(len(found))
        for row in found:
            rows.setdefault((read.steps, row.sid), []).append(row)
    drawing = Drawing([], window, width)
    tracks: dict[tuple[str, str], Track] = {}
    grid = _Grid(window, width)
    by_sid = {r.sid: r for r in refs}
    for (steps, sid), found in rows.items():
        ref = by_sid[sid]
        track = _track(tracks, ref)
        for column in _drawn_as(q.columns, ref, steps):
            track.lines[column.name] = _bucket_line(found, q.mode, q.fill, grid)
    for read in reads:
        states = PathRead(read.steps, tuple(s for s in read.sids if (read.steps, s) not in rows))
        if not states.sids:
            continue
        lines, notice = changes_lines(querier, states, window, q.changes or q.points * len(states.sids))
        if notice:
            drawing.notices.append(notice)
        for sid, line in lines.items():
            ref = by_sid[sid]
            track = _track(tracks, ref)
            for column in _drawn_as(q.columns, ref, read.steps):
                track.lines[column.name] = extracted(line, column.path)
    drawing.tracks = [tracks[key] for key in sorted(tracks, key=lambda k: (k[1], k[0]))]
    return drawing


def resolve_window(querier: HistoryReads, sids: Sequence[int], time: TimeRange) -> tuple[int, int] | None:
    """The window in epoch µs: both ends given, or the open ones taken from
    the data (``span``). None: nothing to draw."""
    start = None if time.start is None else epoch_micros(time.start)
    end = None if time.end is None else epoch_micros(time.end)
    if start is None or end is None:
        found = querier.span(SamplesIn(sids, time))
        if found is None:
            return None
        start = found[0] if start is None else start
        end = found[1] if end is None else end
    return (start, end) if start <= end else None


def _span(window: tuple[int, int]) -> timedelta:
    return timedelta(microseconds=window[1] - window[0])


def window_range(window: tuple[int, int]) -> TimeRange:
    return TimeRange(_datetime(window[0]), _datetime(window[1]))


def _datetime(micros: int) -> datetime:
    return _EPOCH + timedelta(microseconds=micros)


def _drawn_as(columns: Sequence[Column], ref: SeriesRef, steps: tuple[str | int, ...]) -> list[Column]:
    """The columns series ``ref`` is drawn under at the path ``steps``."""
    return [c for c in columns if c.path.attr == ref.attr and c.path.steps == steps]


def path_reads(columns: Sequence[Column], refs: Sequence[SeriesRef]) -> list[PathRead]:
    """One read per distinct path inside the values (plain attributes: one
    read for them all); a series drawn at two paths is in two reads."""
    by_steps: dict[tuple[str | int, ...], list[int]] = {}
    for column in columns:
        sids = by_steps.setdefault(column.path.steps, [])
        sids += [r.sid for r in refs if r.attr == column.path.attr and r.sid not in sids]
    return [PathRead(steps, tuple(sorted(sids))) for steps, sids in by_steps.items() if sids]


def _track(tracks: dict[tuple[str, str], Track], ref: SeriesRef) -> Track:
    key = (ref.entity_type, ref.entity_id)
    track = tracks.get(key)
    if track is None:
        track = tracks[key] = Track(ref.entity_id, ref.entity_type)
    return track


# --- raw samples, when they fit ------------------------------------------------------------------


def _raw(querier: HistoryReads, q: DrawQuery, refs: Sequence[SeriesRef], window: tuple[int, int]) -> Drawing | None:
    """Every sample of the window as stored (``count_up_to`` found at most
    ``most``), or None when some series holds more than ``points`` of them
    (then buckets answer). A sample without a value at a column's path is
    no point of it."""
    sids = sorted({r.sid for r in refs})
    most = q.points * len(sids)
    found = querier.samples(SamplesIn(sids, window_range(window)), most)
    budget.charge_rows(len(found))
    by_sid = {r.sid: r for r in refs}
    tracks: dict[tuple[str, str], Track] = {}
    start = 0
    number = int(Kind.NUMBER)
    while start < len(found):
        sid = found[start][0]
        stop = start
        while stop < len(found) and found[stop][0] == sid:
            stop += 1
        if stop - start > q.points:
            return None
        ref = by_sid[sid]
        rows = found[start:stop]
        times = [row[1] // 1000 for row in rows]
        if {row[2] for row in rows} == {number}:
            values = [row[3] for row in rows]
        else:
            values = [decode(kind, num, txt, js) for _, _, kind, num, txt, js in rows]
        for column in [c for c in q.columns if c.path.attr == ref.attr]:
            extracted = [extract(v, column.path.steps) for v in values] if column.path.steps else values
            if None in extracted:
                kept = [(t, v) for t, v in zip(times, extracted, strict=True) if v is not None]
                line = Line([t for t, _ in kept], [v for _, v in kept])
            else:
                line = Line(times, extracted)
            if line.times:
                _track(tracks, ref).lines[column.name] = line
        start = stop
    return Drawing([tracks[key] for key in sorted(tracks, key=lambda k: (k[1], k[0]))], window, None)


# --- buckets into lines ----------------------------------------------------------------------------


class _Grid:
    """The window's buckets: index ``k`` starts at ``first + k * width``; a
    point of bucket ``k`` is stamped at ``time(k)``, its start inside the window."""

    def __init__(self, window: tuple[int, int], width: timedelta):
        self.start, self.end = window
        self.width = width // _US
        self.first = bucket_start(_datetime(self.start), width)
        self.first_us = epoch_micros(self.first)
        self.count = bucket_count(_datetime(self.start), _datetime(self.end), width)

    def index(self, start_us: int) -> int:
        return (start_us - self.first_us) // self.width

    def time(self, k: int) -> int:
        """Epoch ms."""
        return max(self.first_us + k * self.width, self.start) // 1000


def _number(value: float, integral: bool):
    return int(value) if integral and float(value).is_integer() else value


def _value(row: BucketRow, mode: Mode):
    if mode is Mode.AVG:
        return row.total / row.n
    if mode is Mode.COUNT:
        return row.n
    if mode is Mode.SUM:
        return _number(row.total, row.all_integer)
    picked = {Mode.MIN: row.min, Mode.MAX: row.max, Mode.FIRST: row.first}.get(mode, row.last)
    return _number(picked, row.all_integer)


def _bucket_line(rows: list[BucketRow], mode: Mode, fill: Fill, grid: _Grid) -> Line:
    """One series' buckets (by start) drawn in ``mode``, its empty buckets by ``fill``."""
    if mode is Mode.AUTO:
        mode = Mode.LAST if all(r.all_integer for r in rows) else Mode.AVG
    if mode is Mode.MINMAX:
        return _minmax_line(rows, fill, grid)
    points = [(grid.index(r.start), _value(r, mode)) for r in rows]
    line = Line()
    if fill is Fill.NONE:
        last_k = None
        for k, value in points:
            if last_k is not None and k - last_k > 1:
                line.add(grid.time(last_k + 1), None)  # one null: the line breaks over the gap
            line.add(grid.time(k), value)
            last_k = k
        return line
    by_k = dict(points)
    known = [k for k, _ in points]
    for k in range(grid.count):
        if k in by_k:
            line.add(grid.time(k), by_k[k])
        else:
            line.add(grid.time(k), _filled(fill, k, known, by_k, grid))
    return line


def _filled(fill: Fill, k: int, known: list[int], by_k: dict, grid: _Grid):
    """The value of empty bucket ``k`` (``known``: the buckets with points, ascending)."""
    if fill is Fill.NULL:
        return None
    at = bisect.bisect_left(known, k)
    before = known[at - 1] if at > 0 else None
    if fill is Fill.PREVIOUS:
        return None if before is None else by_k[before]
    after = known[at] if at < len(known) else None
    if before is None or after is None:
        return None
    lo, hi = by_k[before], by_k[after]
    if not _is_number(lo) or not _is_number(hi):
        return None
    t0, t1, t = grid.time(before), grid.time(after), grid.time(k)
    return lo + (hi - lo) * (t - t0) / (t1 - t0) if t1 > t0 else lo


def _is_number(value) -> bool:
    return type(value) in (int, float)


def _minmax_line(rows: list[BucketRow], fill: Fill, grid: _Grid) -> Line:
    """Up to four points a bucket (first, min, max, last at their own times);
    an empty bucket: one point at its start, as ``fill`` says."""
    line = Line()
    by_k = {grid.index(r.start): r for r in rows}
    known = sorted(by_k)
    last_k = None
    span = range(grid.count) if fill is not Fill.NONE else known
    for k in span:
        row = by_k.get(k)
        if row is None:
            line.add(grid.time(k), _minmax_fill(fill, k, known, by_k, grid))
            continue
        if fill is Fill.NONE and last_k is not None and k - last_k > 1:
            line.add(grid.time(last_k + 1), None)
        last_k = k
        integral = row.all_integer
        seen = set()
        low = row.first_t if row.min_t is None else row.min_t  # always asked in this mode (``extreme_times``)
        high = row.first_t if row.max_t is None else row.max_t
        for t, value in sorted(((row.first_t, row.first), (low, row.min), (high, row.max), (row.last_t, row.last))):
            if (t, value) not in seen:
                seen.add((t, value))
                line.add(t // 1000, _number(value, integral))
    return line


def _minmax_fill(fill: Fill, k: int, known: list[int], by_k: dict[int, BucketRow], grid: _Grid):
    if fill is Fill.NULL:
        return None
    at = bisect.bisect_left(known, k)
    before = by_k[known[at - 1]] if at > 0 else None
    if fill is Fill.PREVIOUS:
        return None if before is None else _number(before.last, before.all_integer)
    after = by_k[known[at]] if at < len(known) else None
    if before is None or after is None:
        return None
    t0, t1, t = before.last_t / 1000, after.first_t / 1000, grid.time(k)
    return before.last + (after.first - before.last) * (t - t0) / (t1 - t0) if t1 > t0 else before.last


# --- transitions ----------------------------------------------------------------------------------


def changes_lines(
    querier: HistoryReads,
    read: PathRead,
    window: tuple[int, int],
    limit: int,
) -> tuple[dict[int, Line], str | None]:
    """Each series' transitions in the window as points (the stored value),
    then its last sample (the same value) where it came later: a line of
    states ends where the data ends. And the notice when older transitions
    were left out (``limit``)."""
    page = querier.state_changes(ChangesRead(list(read.sids), window_range(window), max(1, limit), read.steps))
    budget.charge_rows(len(page.changes))
    lines: dict[int, Line] = {}
    for change in page.changes:
        lines.setdefault(change.sid, Line()).add(change.time // 1000, change_value(change))
    for sid, iso in querier.latest_index(SamplesIn(list(lines), window_range(window))):
        line = lines[sid]
        last = ms_of_iso(iso)
        if last > line.times[-1]:
            line.add(last, line.values[-1])
    notice = None
    if page.truncated and page.changes:
        notice = (
            f"more than {limit} state changes in the window: only the newest {len(page.changes)} are shown, "
            f"from {_iso(page.changes[0].time)} on; narrow the window to see the older ones"
        )
    return lines, notice


def change_value(change: StateChange):
    return decode(change.kind, change.num, change.txt, change.js)


def extracted(line: Line, path: ValuePath) -> Line:
    if not path.steps:
        return line
    return Line(list(line.times), [extract(v, path.steps) for v in line.values])


def _iso(micros: int) -> str:
    return _datetime(micros).isoformat(timespec="milliseconds").replace("+00:00", "Z")
