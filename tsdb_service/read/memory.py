"""Every read of the seam, answered from Python lists: for tests of the
layers above storage (``history``, the faces), and for embedders who want to
serve a few samples without a database.

``MemoryQuerier`` keeps series and samples as the SQL backends store them
(one ``MemorySample`` per stored row, the columns of ``samples``) and answers
each read as the SQL does, so a face tested on it behaves as on DuckDB or
PostgreSQL; ``tests/test_memory_querier.py`` holds the two against each
other on the same data. It is not fast (every read scans) and keeps no
rolled-up hours. ``sample`` builds a row from a plain Python value.

``http.memory.MemoryStore`` serves it to routes.
"""

from __future__ import annotations

import itertools
import threading
from collections import defaultdict
from collections.abc import Callable, Iterable, Iterator, Sequence
from datetime import UTC, datetime, timedelta
from typing import Any, NamedTuple, TypeVar

import orjson
import pyarrow as pa

from tsdb_service.core.idpattern import compiled
from tsdb_service.core.model import Kind, client_instance_id, instance_iid
from tsdb_service.core.query import (
    ANY_INSTANCE,
    ARRAY_INSTANCE,
    AggBranch,
    AggregateRow,
    AggrMethod,
    AggrPeriod,
    ExtentRow,
    FirstLocationRow,
    GeometryRow,
    InstanceAggregateRow,
    InstanceRow,
    InstanceValueRow,
    InstanceWindow,
    LastValueRow,
    LatestRow,
    LocationRow,
    Prefilter,
    RawRow,
    RowMask,
    Scope,
    SeriesRef,
    StoredSample,
    TimeRange,
    ValueTest,
    box_passes,
    extent_prefilter,
)
from tsdb_service.core.timefmt import iso_ms
from tsdb_service.read import Querier
from tsdb_service.read.buckets import BucketRead, BucketRow, ChangesPage, ChangesRead, StateChange, TimedSample
from tsdb_service.read.bulk import EXPORT_COLUMNS, Columns, SampleBatches
from tsdb_service.read.instances import SeparateScans
from tsdb_service.read.requests import (
    AggregateRead,
    ExportRead,
    ExtentsNear,
    InstanceAggregateRead,
    InstanceLocations,
    InstanceLookup,
    InstancePage,
    InstancesIn,
    InstancesMatching,
    InstancesRead,
    LocatedSelect,
    LocationsIn,
    RowsRead,
    SamplesIn,
    SeriesSelect,
    ValuesAt,
)

T = TypeVar("T")
_EPOCH = datetime(1970, 1, 1)
_NUMERIC = (Kind.NUMBER, Kind.INTEGER)
_TEXT = (Kind.TEXT, Kind.RELATIONSHIP)
_X_KINDS = (Kind.NUMBER, Kind.INTEGER, Kind.BOOLEAN, Kind.DATETIME)


class MemorySample(NamedTuple):
    """One stored sample: the columns of the ``samples`` table. Times are
    naive UTC datetimes, as the SQL backends hold them."""

    rid: int
    sid: int
    iid: int
    t: datetime
    kind: int
    atype: str | None = None
    num: float | None = None
    txt: str | None = None
    js: str | None = None
    geo: str | None = None
    lon: float | None = None
    lat: float | None = None
    min_lon: float | None = None
    min_lat: float | None = None
    max_lon: float | None = None
    max_lat: float | None = None
    md: str | None = None
    observed_at: datetime | None = None
    created_at: datetime | None = None
    modified_at: datetime | None = None
    deleted_at: datetime | None = None

    @property
    def t_us(self) -> int:
        return _micros(self.t)

    @property
    def box(self) -> tuple[float, float, float, float] | None:
        if self.min_lon is None or self.min_lat is None or self.max_lon is None or self.max_lat is None:
            return None
        return (self.min_lon, self.min_lat, self.max_lon, self.max_lat)


def sample(rid: int, sid: int, t: datetime, value: Any, *, iid: int | None = None, **columns: Any) -> MemorySample:
    """A stored row for a plain Python ``value``, stored as the backends
    store it: a bool as BOOLEAN, an int as INTEGER, a float as NUMBER, a str
    as TEXT, a dict or list as STRUCTURED, None as NULL; a GeoJSON geometry
    (a dict with ``type`` and ``coordinates``) given as ``geo=`` instead.
    ``columns``: any other column (``atype``, ``observed_at``, ``md``...)."""
    naive = t.astimezone(UTC).replace(tzinfo=None) if t.tzinfo else t
    values = _value_columns(value, columns.pop("geo", None))
    return MemorySample(rid, sid, rid if iid is None else iid, naive, **values, **columns)


def _value_columns(value: Any, geometry: dict | None) -> dict[str, Any]:
    if geometry is not None:
        xs, ys = _coordinates(geometry["coordinates"])
        text = orjson.dumps(geometry).decode()
        box = {"min_lon": min(xs), "min_lat": min(ys), "max_lon": max(xs), "max_lat": max(ys)}
        point = geometry["type"] == "Point"
        return {"kind": Kind.GEO, "js": text, "geo": text, "lon": xs[0] if point else None,
                "lat": ys[0] if point else None, **box}  # fmt: skip
    if value is None:
        return {"kind": Kind.NULL}
    if isinstance(value, bool):
        return {"kind": Kind.BOOLEAN, "num": float(value), "js": "true" if value else "false"}
    if isinstance(value, int):
        return {"kind": Kind.INTEGER, "num": float(value)}
    if isinstance(value, float):
        return {"kind": Kind.NUMBER, "num": value}
    if isinstance(value, str):
        return {"kind": Kind.TEXT, "txt": value}
    return {"kind": Kind.STRUCTURED, "js": orjson.dumps(value).decode()}


def _coordinates(nested: Any) -> tuple[list[float], list[float]]:
    if isinstance(nested[0], (int, float)):
        return [float(nested[0])], [float(nested[1])]
    xs: list[float] = []
    ys: list[float] = []
    for part in nested:
        x, y = _coordinates(part)
        xs += x
        ys += y
    return xs, ys


class MemoryQuerier(SeparateScans, Querier):
    """Series and samples in lists; every read as the SQL backends answer it."""

    shared_scan = False

    def __init__(self, series: Iterable[tuple[str, SeriesRef]] = (), samples: Iterable[MemorySample] = ()):
        self._lock = threading.Lock()
        self._series: dict[int, tuple[str, SeriesRef]] = {}
        self._samples: dict[int, list[MemorySample]] = defaultdict(list)
        for tenant, ref in series:
            self.add_series(tenant, ref)
        self.add_samples(samples)

    # -- loading -----------------------------------------------------------------

    def add_series(self, tenant: str, ref: SeriesRef) -> None:
        with self._lock:
            self._series[ref.sid] = (tenant, ref)

    def add_samples(self, samples: Iterable[MemorySample]) -> None:
        with self._lock:
            touched = set()
            for s in samples:
                self._samples[s.sid].append(s)
                touched.add(s.sid)
            for sid in touched:
                self._samples[sid].sort(key=lambda s: (s.t, s.rid, s.iid))

    def _of(self, sids: Iterable[int]) -> Iterator[MemorySample]:
        for sid in sorted(set(sids)):
            yield from self._samples.get(sid, ())

    # -- the series catalogue ------------------------------------------------------

    def series(self, ask: SeriesSelect) -> list[SeriesRef]:
        e = ask.entities
        pattern = None if e.id_pattern is None else compiled(e.id_pattern)
        return [
            ref
            for tenant, ref in sorted(self._series.values(), key=lambda tr: tr[1].sid)
            if tenant == ask.scope.tenant
            and ask.scope.matches(ref.service_path)
            and (e.ids is None or ref.entity_id in e.ids)
            and (e.types is None or ref.entity_type in e.types)
            and (pattern is None or pattern.search(ref.entity_id) is not None)
            and (ask.attrs is None or ref.attr in ask.attrs)
        ]

    def series_names(self, scope: Scope) -> dict[str, dict[str, tuple[str, ...]]]:
        names: dict[str, dict[str, tuple[str, ...]]] = {}
        for tenant, ref in sorted(self._series.values(), key=lambda tr: tr[1].sid):
            stored = names.setdefault(ref.entity_type, {}).get(ref.ld_attr, ()) if tenant == scope.tenant else None
            if stored is not None and ref.attr not in stored:
                names[ref.entity_type][ref.ld_attr] = (*stored, ref.attr)
        return names

    def tenants(self) -> list[str]:
        return sorted({tenant for tenant, _ in self._series.values()})

    def sids_with_samples(self, sids: Sequence[int]) -> set[int]:
        return {sid for sid in sids if self._samples.get(sid)}

    # -- history reads ---------------------------------------------------------------

    def _in(self, sids: Sequence[int], time: TimeRange, mask: RowMask | None = None) -> list[MemorySample]:
        start, end = _naive(time.start), _naive(time.end)
        rows = [s for s in self._of(sids) if (start is None or s.t >= start) and (end is None or s.t <= end)]
        return rows if mask is None else [s for s in rows if _kept(mask, s)]

    def raw_rows(self, ask: RowsRead) -> list[RawRow]:
        rows = self._in(ask.sids, ask.time, ask.mask)
        if ask.one_per_row:
            rows.sort(key=lambda s: (s.t, s.rid), reverse=ask.newest_first)
            picked = rows[ask.offset : ask.offset + ask.limit]
            if ask.newest_first:
                picked.reverse()
        else:
            by_rid: dict[int, list[MemorySample]] = defaultdict(list)
            for s in rows:
                by_rid[s.rid].append(s)
            pick = max if ask.newest_first else min
            order = sorted(by_rid, key=lambda rid: (pick(s.t for s in by_rid[rid]), rid), reverse=ask.newest_first)
            wanted = set(order[ask.offset : ask.offset + ask.limit])
            picked = sorted((s for s in rows if s.rid in wanted), key=lambda s: (s.t, s.rid, s.sid))
        return [(s.sid, s.rid, iso_ms(s.t), s.kind, s.num, s.txt, s.js) for s in picked]

    def aggregate(self, ask: AggregateRead) -> list[AggregateRow]:
        out: list[AggregateRow] = []
        for number, branch in enumerate(ask.branches):
            groups: dict[tuple[int, str | None], list[MemorySample]] = defaultdict(list)
            for s in self._in(branch.sids, ask.time, ask.mask):
                period = ask.agg.period
                groups[(s.sid, None if period is None else iso_ms(_truncate(s.t, period)))].append(s)
            out += [
                _aggregate_row(number, sid, bucket, rows, branch, ask.agg.method)
                for (sid, bucket), rows in groups.items()
            ]
        return out

    def latest_index(self, ask: SamplesIn) -> list[LatestRow]:
        latest: dict[int, datetime] = {}
        for s in self._in(ask.sids, ask.time, ask.mask):
            if s.sid not in latest or s.t > latest[s.sid]:
                latest[s.sid] = s.t
        return [LatestRow(sid, iso_ms(t)) for sid, t in latest.items()]

    def last_values(self, sids: Sequence[int]) -> list[LastValueRow]:
        out = []
        for sid in sorted(set(sids)):
            rows = self._samples.get(sid)
            if rows:
                s = max(rows, key=lambda r: (r.t, r.rid))
                out.append(LastValueRow(sid, iso_ms(s.t), s.kind, s.atype, s.num, s.txt, s.js))
        return out

    def values_at(self, ask: ValuesAt) -> list[LastValueRow]:
        at = _naive(ask.at)
        out = []
        for sid in sorted(set(ask.sids)):
            rows = [r for r in self._samples.get(sid, ()) if at is None or r.t <= at]
            if rows:
                s = max(rows, key=lambda r: (r.t, r.rid))
                out.append(LastValueRow(sid, iso_ms(s.t), s.kind, s.atype, s.num, s.txt, s.js))
        return out

    def count(self, ask: SamplesIn) -> int:
        return len(self._in(ask.sids, ask.time, ask.mask))

    # -- long windows ---------------------------------------------------------------------

    def buckets(self, ask: BucketRead) -> list[BucketRow]:
        width = ask.width // timedelta(microseconds=1)
        groups: dict[tuple[int, int], list[tuple[int, int, float, bool]]] = defaultdict(list)
        for s in self._in(ask.sids, ask.time):
            number = _number_of(s, ask.steps)
            if number is not None:
                t = s.t_us
                groups[(s.sid, t - t % width)].append((t, s.rid, number[0], number[1]))
        found = [_bucket_row(sid, start, rows) for (sid, start), rows in sorted(groups.items())]
        return found if ask.extreme_times else [row._replace(min_t=None, max_t=None) for row in found]

    def state_changes(self, ask: ChangesRead) -> ChangesPage:
        found: list[tuple[MemorySample, int | None]] = []
        for sid in sorted(set(ask.sids)):
            previous: Any = _NO_SAMPLE
            before = None
            for s in sorted(self._in([sid], ask.time), key=lambda r: (r.t, r.rid)):
                state = _state_of(s, ask.steps)
                if state != previous:
                    found.append((s, before))
                previous, before = state, s.t_us
        found.sort(key=lambda pair: (pair[0].t, pair[0].rid, pair[0].sid))
        kept = found[max(0, len(found) - ask.limit) :] if ask.limit > 0 else []
        changes = [StateChange(s.sid, s.t_us, s.kind, s.num, s.txt, s.js, before) for s, before in kept]
        return ChangesPage(changes, len(kept) < len(found))

    def span(self, ask: SamplesIn) -> tuple[int, int] | None:
        times = [s.t_us for s in self._in(ask.sids, ask.time)]
        return (min(times), max(times)) if times else None

    def count_up_to(self, ask: SamplesIn, most: int) -> int:
        return min(len(self._in(ask.sids, ask.time)), max(0, most))

    def samples(self, ask: SamplesIn, most: int) -> list[TimedSample]:
        rows = sorted(self._in(ask.sids, ask.time), key=lambda s: (s.sid, s.t, s.rid))[: max(0, most)]
        return [(s.sid, s.t_us, s.kind, s.num, s.txt, s.js) for s in rows]

    # -- locations ------------------------------------------------------------------------

    def latest_geometries(self, ask: LocationsIn) -> list[GeometryRow]:
        out = []
        for sid in sorted(set(ask.sids)):
            located = [s for s in self._in([sid], ask.time) if s.kind == Kind.GEO]
            if located:
                s = max(located, key=lambda r: (r.t, r.rid))
                if s.geo is not None and _passes(ask.prefilter, s.box):
                    out.append(GeometryRow(sid, s.geo))
        return out

    def location_extents(self, ask: ExtentsNear) -> list[ExtentRow]:
        out = []
        for sid in sorted(set(ask.sids)):
            located = self._located(sid)
            boxes = [s.box for s in located if s.box is not None]
            if not boxes:
                continue
            extent = (
                min(b[0] for b in boxes),
                min(b[1] for b in boxes),
                max(b[2] for b in boxes),
                max(b[3] for b in boxes),
            )
            if _passes(extent_prefilter(ask.prefilter), extent):
                first = located[0]
                out.append(ExtentRow(sid, *extent, first.t_us, first.rid))
        return out

    def _located(self, sid: int) -> list[MemorySample]:
        return [s for s in self._samples.get(sid, ()) if s.kind == Kind.GEO and s.geo is not None and s.box]

    def located_series(self, ask: LocatedSelect) -> list[SeriesRef]:
        scope = ask.scope
        refs = [
            ref
            for tenant, ref in self._series.values()
            if tenant == scope.tenant
            and scope.matches(ref.service_path)
            and ref.entity_type in ask.types
            and ref.attr in ask.attrs
        ]
        near = {row.sid for row in self.location_extents(ExtentsNear([r.sid for r in refs], ask.prefilter))}
        return sorted((r for r in refs if r.sid in near), key=lambda r: r.sid)

    def first_locations(self, sids: Sequence[int]) -> list[FirstLocationRow]:
        out = []
        for sid in sorted(set(sids)):
            located = [s for s in self._samples.get(sid, ()) if s.kind == Kind.GEO and s.geo is not None]
            if located:
                out.append(FirstLocationRow(sid, located[0].t_us, located[0].rid))
        return out

    def location_samples(self, ask: LocationsIn) -> list[LocationRow]:
        start = _naive(ask.time.start)
        out: list[LocationRow] = []
        for sid in sorted(set(ask.sids)):
            located = [s for s in self._samples.get(sid, ()) if s.kind == Kind.GEO and s.geo is not None]
            before = [s for s in located if start is not None and s.t < start]
            rows = [*before[-1:], *(s for s in self._in([sid], ask.time) if s.kind == Kind.GEO and s.geo is not None)]
            for s in rows:
                box = s.box
                if box is None:  # every stored geometry has its box
                    continue
                ok = _passes(ask.prefilter, box)
                point = box[0] == box[2] and box[1] == box[3]
                out.append((sid, s.t_us, s.rid, ok, point, box[0], box[1], s.geo if ok and not point else None))
        return out

    # -- NGSI-LD instances ------------------------------------------------------------------

    def _window(self, sids: Sequence[int], window: InstanceWindow) -> list[tuple[datetime, MemorySample]]:
        """(time property, sample) of the instances in ``window``."""
        start, end = _naive(window.start), _naive(window.end)
        spans: dict[int, list[tuple[datetime | None, datetime | None]]] = defaultdict(list)
        for sid, span_start, span_end in window.spans:
            spans[sid].append((_naive(span_start), _naive(span_end)))
        out = []
        for s in self._of(sids):
            at = _time_property(s, window.timeproperty)
            if at is None or (start is not None and at < start) or (end is not None and at >= end):
                continue
            if s.sid not in spans or any((a is None or at >= a) and (b is None or at < b) for a, b in spans[s.sid]):
                out.append((at, s))
        return out

    def temporal_instances(self, ask: InstancesRead) -> list[InstanceRow]:
        found = self._window(ask.sids, ask.window)
        newest = ask.newest_first or ask.last_n is not None
        if ask.last_n is not None:
            per_sid: dict[int, list[tuple[datetime, MemorySample]]] = defaultdict(list)
            for at, s in found:
                per_sid[s.sid].append((at, s))
            found = [
                pair
                for rows in per_sid.values()
                for pair in sorted(rows, key=lambda p: (p[0], p[1].iid), reverse=True)[: ask.last_n]
            ]
        if ask.limit is not None:
            found = sorted(found, key=lambda p: (p[0], p[1].iid), reverse=newest)[: ask.limit]
        refs = {sid: ref for sid, (_, ref) in self._series.items()}
        rows = [_instance_row(at, s, refs.get(s.sid)) for at, s in found]
        rows.sort(key=lambda r: (r.sid, r.at, r.iid))
        return rows

    def instance_page(self, ask: InstancePage) -> tuple[list[InstanceRow], int | None]:
        found = [(at, s) for at, s in self._window(ask.sids, ask.window)]
        if ask.through_iid is not None:
            found = [(at, s) for at, s in found if s.iid <= ask.through_iid]
        top = ask.through_iid if ask.through_iid is not None else max((s.iid for _, s in found), default=None)
        per_sid: dict[int, list[tuple[datetime, MemorySample]]] = defaultdict(list)
        for at, s in found:
            per_sid[s.sid].append((at, s))
        ranked = []
        for sid, rows in per_sid.items():
            rows.sort(key=lambda p: (p[0], p[1].iid), reverse=not ask.ascending)
            end = None if ask.size is None else ask.offset + ask.size
            ranked += [(rank, sid, pair) for rank, pair in enumerate(rows[ask.offset : end], start=ask.offset + 1)]
        ranked.sort(key=lambda r: (r[0], r[1]))
        page = ranked[: ask.limit]
        refs = {sid: ref for sid, (_, ref) in self._series.items()}
        rows_out = [_instance_row(at, s, refs.get(s.sid)) for _, _, (at, s) in page]
        rows_out.sort(key=lambda r: (r.sid, r.at, r.iid))
        return rows_out, top if page else ask.through_iid

    def instances_matching(self, ask: InstancesMatching) -> set[int]:
        return {s.sid for _, s in self._window(ask.sids, ask.window) if _test(ask.test, s)}

    def instance_values(self, ask: InstancesIn) -> list[InstanceValueRow]:
        seen = {
            (s.sid, s.kind, s.num, s.txt, s.js, s.md): None
            for _, s in self._window(ask.sids, ask.window)
            if s.kind != Kind.NULL
        }
        return list(seen)

    def location_instances(self, ask: InstanceLocations) -> list[tuple[int, str]]:
        seen = {
            (s.sid, s.geo): None
            for _, s in self._window(ask.sids, ask.window)
            if s.kind == Kind.GEO and s.geo is not None and (ask.prefilter is None or _passes(ask.prefilter, s.box))
        }
        return list(seen)

    def instance_aggregate(self, ask: InstanceAggregateRead) -> list[InstanceAggregateRow]:
        found = [(_micros(at), s) for at, s in self._window(ask.sids, ask.window) if s.kind != Kind.NULL]
        periods = ask.periods
        origin = periods.origin_us
        if periods.step_us is not None and origin is None:
            origin = min((tp for tp, _ in found), default=0)
        groups: dict[tuple, list[tuple[int, MemorySample]]] = defaultdict(list)
        for tp, s in found:
            bucket = _bucket(tp, periods.step_us, origin, periods.edges)
            if bucket is not None:
                groups[(s.sid, bucket, s.kind, int(_is_array(s)), s.atype)].append((tp, s))
        first = periods.step_us is None and not periods.edges
        return [_instance_aggregate_row(key, rows, ask.methods, first) for key, rows in groups.items()]

    def instance_span(self, ask: InstancesIn) -> tuple[int, int] | None:
        times = [_micros(at) for at, s in self._window(ask.sids, ask.window) if s.kind != Kind.NULL]
        return (min(times), max(times)) if times else None

    def instance_at(self, ask: InstanceLookup) -> tuple[int, int] | None:
        iid = instance_iid(ask.instance_id)
        for s in self._of(ask.sids):
            if (s.iid == iid) if iid is not None else client_instance_id(s.md) == ask.instance_id:
                return s.sid, s.iid
        return None

    # -- bulk reads ------------------------------------------------------------------------------

    def export_batches(self, ask: ExportRead) -> SampleBatches:
        refs = {sid: (tenant, ref) for sid, (tenant, ref) in self._series.items()}
        rows = sorted(self._in(ask.sids, ask.time), key=lambda s: (s.t, s.rid, s.sid))
        pending = [rows[i : i + ask.batch_rows] for i in range(0, len(rows), ask.batch_rows)]
        batches = SampleBatches()
        batches.read = lambda: _export_columns(pending.pop(0), refs) if pending else None
        return batches

    def sample_counts(self) -> dict[str, int]:
        counts: dict[str, int] = defaultdict(int)
        for sid, rows in self._samples.items():
            if rows and sid in self._series:
                counts[self._series[sid][0]] += len(rows)
        return dict(counts)

    def type_counts(self, before: datetime | None = None) -> dict[tuple[str, str], tuple[int, int]]:
        rids: dict[tuple[str, str], set[int]] = defaultdict(set)
        counts: dict[tuple[str, str], int] = defaultdict(int)
        end = _naive(before)
        for sid, every in self._samples.items():
            rows = every if end is None else [s for s in every if s.t < end]
            if rows and sid in self._series:
                tenant, ref = self._series[sid]
                rids[tenant, ref.entity_type].update(s.rid for s in rows)
                counts[tenant, ref.entity_type] += len(rows)
        return {key: (len(rids[key]), n) for key, n in counts.items()}

    def stored_samples(self, batch_rows: int) -> Iterator[list[StoredSample]]:
        every = sorted((s for rows in self._samples.values() for s in rows), key=lambda s: (s.rid, s.iid))
        for i in range(0, len(every), batch_rows):
            yield [_stored(s) for s in every[i : i + batch_rows]]


# -- how the SQL computes, in Python -----------------------------------------------------------------


def _micros(moment: datetime) -> int:
    return (moment - _EPOCH) // timedelta(microseconds=1)


def _naive(moment: datetime | None) -> datetime | None:
    if moment is None or moment.tzinfo is None:
        return moment
    return moment.astimezone(UTC).replace(tzinfo=None)


def _kept(mask: RowMask, s: MemorySample) -> bool:
    key = (s.t_us, s.rid)
    return any(key >= (t0, r0) and (t1 is None or key < (t1, r1)) for t0, r0, t1, r1 in mask.intervals.get(s.sid, ()))


def _passes(prefilter: Prefilter | None, box: tuple[float, float, float, float] | None) -> bool:
    if prefilter is None:
        return True
    return box is not None and box_passes(prefilter[0], box, prefilter[1])


def _truncate(t: datetime, period: AggrPeriod) -> datetime:
    if period is AggrPeriod.YEAR:
        return t.replace(month=1, day=1, hour=0, minute=0, second=0, microsecond=0)
    if period is AggrPeriod.MONTH:
        return t.replace(day=1, hour=0, minute=0, second=0, microsecond=0)
    if period is AggrPeriod.DAY:
        return t.replace(hour=0, minute=0, second=0, microsecond=0)
    if period is AggrPeriod.HOUR:
        return t.replace(minute=0, second=0, microsecond=0)
    if period is AggrPeriod.MINUTE:
        return t.replace(second=0, microsecond=0)
    return t.replace(microsecond=0)


def _at_path(s: MemorySample, steps: tuple[str | int, ...]) -> Any:
    """The JSON value at ``steps`` in a sample's ``js`` (None when missing)."""
    if s.js is None:
        return None
    node: Any = orjson.loads(s.js)
    for step in steps:
        node = _step(node, step)
        if node is None:
            return None
    return node


def _step(node: Any, step: str | int) -> Any:
    """One step into a JSON value: an array index or an object member."""
    if isinstance(step, int):
        return node[step] if isinstance(node, list) and -len(node) <= step < len(node) else None
    return node.get(step) if isinstance(node, dict) else None


_AGGREGATES: dict[AggrMethod, Callable[[list[float]], float]] = {
    AggrMethod.SUM: sum,
    AggrMethod.AVG: sum,
    AggrMethod.MIN: min,
    AggrMethod.MAX: max,
}


def _aggregate_row(
    number: int, sid: int, bucket: str | None, rows: list[MemorySample], branch: AggBranch, method: AggrMethod
) -> AggregateRow:
    if branch.steps:
        values = [_at_path(s, branch.steps) for s in rows]
        present = sum(v is not None for v in values)
        numbers = [float(v) for v in values if isinstance(v, (int, float)) and not isinstance(v, bool)]
        integers = sum(isinstance(v, int) and not isinstance(v, bool) for v in values)
    else:
        present = sum(s.kind != Kind.NULL for s in rows)
        numbers = [s.num for s in rows if s.kind in _NUMERIC and s.num is not None]
        integers = sum(s.kind == Kind.INTEGER and s.num is not None for s in rows)
    fn = _AGGREGATES.get(method)
    value = fn(numbers) if fn is not None and numbers else None
    all_integer = integers == len(numbers) if numbers else None
    return AggregateRow(number, sid, bucket, present, len(numbers), value, all_integer)


_NO_SAMPLE = object()


def _number_of(s: MemorySample, steps: tuple[str | int, ...]) -> tuple[float, bool] | None:
    """The sample's number (and whether it is an integer) as the bucket query reads it."""
    if not steps:
        if s.kind in _NUMERIC and s.num is not None:
            return s.num + 0.0, s.kind == Kind.INTEGER
        return None
    value = _at_path(s, steps)
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        return float(value) + 0.0, isinstance(value, int)
    return None


def _bucket_row(sid: int, start: int, rows: list[tuple[int, int, float, bool]]) -> BucketRow:
    """``rows``: (time µs, row id, number, is integer). Ties: the earliest
    (time, row id) wins; for the last, the latest."""
    low = min(rows, key=lambda r: (r[2], r[0], r[1]))
    high = min(rows, key=lambda r: (-r[2], r[0], r[1]))
    first = min(rows, key=lambda r: (r[0], r[1]))
    last = max(rows, key=lambda r: (r[0], r[1]))
    return BucketRow(
        sid,
        start,
        len(rows),
        sum(r[2] for r in rows),
        all(r[3] for r in rows),
        low[2],
        low[0],
        high[2],
        high[0],
        first[2],
        first[0],
        last[2],
        last[0],
    )


def _state_of(s: MemorySample, steps: tuple[str | int, ...]) -> Any:
    """What two samples share when they hold the same state."""
    if not steps or s.js is None:
        return (s.kind, s.num, s.txt, s.js) if not steps else None
    node: Any = orjson.loads(s.js)
    for step in steps:
        if isinstance(step, int):
            if not (isinstance(node, list) and -len(node) <= step < len(node)):
                return None  # missing: SQL NULL, unlike a JSON null
        elif not (isinstance(node, dict) and step in node):
            return None
        node = node[step]
    return orjson.dumps(node)


def _time_property(s: MemorySample, name: str) -> datetime | None:
    if name == "observedAt":
        return s.observed_at if s.observed_at is not None else s.t
    return {"createdAt": s.created_at, "modifiedAt": s.modified_at, "deletedAt": s.deleted_at}[name]


def _instance_row(at: datetime, s: MemorySample, ref: SeriesRef | None) -> InstanceRow:
    return InstanceRow(
        s.sid,
        s.iid,
        at,
        s.t,
        s.observed_at,
        s.created_at,
        s.modified_at,
        s.deleted_at,
        None if ref is None else ref.dataset_id,
        s.kind,
        s.atype,
        s.num,
        s.txt,
        s.js,
        s.md,
    )


def _test(test: ValueTest, s: MemorySample) -> bool:
    if test.op is None:
        return s.kind != Kind.NULL
    if test.op == ANY_INSTANCE:
        return True
    if test.op == ARRAY_INSTANCE:
        return _is_array(s)
    if isinstance(test.value, str):
        have: Any = s.txt if s.kind in _TEXT else None
    else:
        have = s.num if s.kind in _NUMERIC else None
    if have is None:
        return False
    return {
        "==": have == test.value,
        ">": have > test.value,
        ">=": have >= test.value,
        "<": have < test.value,
        "<=": have <= test.value,
    }[test.op]


def _is_array(s: MemorySample) -> bool:
    return s.kind == Kind.STRUCTURED and s.js is not None and s.js.startswith("[")


def _x(s: MemorySample) -> float | None:
    if s.kind in _X_KINDS:
        return s.num
    if _is_array(s):
        return float(len(orjson.loads(s.js or "[]")))
    return None


def _bucket(tp: int, step: int | None, origin: int | None, edges: tuple[int, ...]) -> int | None:
    if edges:
        for lo, hi in itertools.pairwise(edges):
            if lo <= tp < hi:
                return lo
        return None
    if step is None or origin is None:
        return 0
    return origin + step * ((tp - origin) // step)


def _instance_aggregate_row(
    key: tuple, rows: list[tuple[int, MemorySample]], methods: Sequence[str], first: bool
) -> InstanceAggregateRow:
    wanted = set(methods)
    xs = [x for _, s in rows if (x := _x(s)) is not None]
    texts = [s.txt for _, s in rows if s.txt is not None]
    times = [tp for tp, _ in rows]
    distinct = {s.txt if s.txt is not None else s.js if s.js is not None else repr(s.num) for _, s in rows}

    def when(needed: object, value: Any) -> Any:
        return value if needed else None

    sid, bucket, kind, is_array, atype = key
    return (
        sid,
        bucket,
        kind,
        is_array,
        atype,
        when("totalCount" in wanted, len(rows)),
        when("distinctCount" in wanted, len(distinct)),
        when(wanted - {"totalCount", "distinctCount"}, len(xs)),
        when(wanted & {"sum", "avg", "stddev"}, sum(xs) if xs else None),
        when(wanted & {"stddev", "sumsq"}, sum(x * x for x in xs) if xs else None),
        when("min" in wanted, min(xs, default=None)),
        when("max" in wanted, max(xs, default=None)),
        when("min" in wanted, min(texts, default=None)),
        when("max" in wanted, max(texts, default=None)),
        when(first, min(times)),
        max(times),
    )


_EXPORT_TYPES = (pa.string(),) * 5 + (pa.float64(), pa.string(), pa.bool_(), pa.string())


def _export_columns(rows: list[MemorySample], refs: dict[int, tuple[str, SeriesRef]]) -> Columns:
    """Rows in ``EXPORT_COLUMNS``, time as epoch µs (as PostgreSQL sends it)."""
    table: list[list] = [[] for _ in EXPORT_COLUMNS]
    for s in rows:
        ref = refs[s.sid][1]
        values = (
            s.t_us,
            ref.entity_id,
            ref.entity_type,
            ref.service_path,
            ref.attr,
            s.atype,
            s.num if s.kind in _NUMERIC else None,
            s.txt if s.kind in (*_TEXT, Kind.DATETIME) else None,
            (s.num != 0) if s.kind == Kind.BOOLEAN and s.num is not None else None,
            s.js if s.kind in (Kind.STRUCTURED, Kind.GEO) else None,
        )
        for column, value in zip(table, values, strict=True):
            column.append(value)
    return [pa.array(table[0], type=pa.int64())] + [
        pa.array(column, type=kind) for column, kind in zip(table[1:], _EXPORT_TYPES, strict=True)
    ]


def _stored(s: MemorySample) -> StoredSample:
    return StoredSample(
        s.rid,
        s.sid,
        s.t,
        s.kind,
        s.atype,
        s.num,
        s.txt,
        s.js,
        s.geo,
        s.lon,
        s.lat,
        s.min_lon,
        s.min_lat,
        s.max_lon,
        s.max_lat,
        s.md,
        s.observed_at,
        s.created_at,
        s.modified_at,
        s.deleted_at,
    )
