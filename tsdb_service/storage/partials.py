"""Hourly aggregate partials of recently aggregated series, in memory.

An hourly (daily, monthly, yearly) average over a day of 20 series is a
grouped scan of ~30,000 samples in the database, repeated identically by
every dashboard refresh. Kept per series and UTC hour, the partials that
``SqlQuerier.aggregate`` computes (samples with a value, numbers, integers,
the numbers' sum, min and max) answer it from memory, exactly:

* loaded by one grouped statement the first time a series is aggregated
  (every hour from the start of the requested window on: an entry covers
  all the series' samples from its ``lo`` hour onwards);
* kept current by the writer, which publishes every committed sample;
* dropped for series touched by any delete, instance replacement or
  retention batch (whatever calls ``drop``), and all at once on a reopen;
* or, where other processes write too (PostgreSQL), checked against the
  series' change count in the database before every use, and loaded again
  when it moved (``series(versions=...)``);
* at most ``max_hours`` hours in all, least recently aggregated series out.

Sums are kept exact: an hour's sum is a short list of floats whose exact
(real-number) sum is the sum of its numbers (``exact_parts``), and a bucket
is ``math.fsum`` over its hours' lists, i.e. the correctly rounded sum of
all its numbers, whatever the order samples arrived in or hours combine.
SQL adds in scan order; the two agree whenever SQL's additions are exact
(integers, binary fractions), and differ otherwise only by SQL's rounding.

An hour cut by ``fromDate``/``toDate`` is used only when all its samples
lie inside the window (its first and last sample times are kept); the
caller computes the others' in-window samples with SQL.

Races with the writer (one writer thread: row ids grow in commit order): a
load registers its series before its query, the writer's publishes for them
are buffered meanwhile and replayed after the load for rows the load's
snapshot did not see (row id above the largest it saw for that series). A
drop during a load voids it for the series dropped.
"""

from __future__ import annotations

import bisect
import math
import threading
from collections import OrderedDict
from collections.abc import Callable, Iterable, Mapping, Sequence
from datetime import UTC, datetime

from tsdb_service.core.model import Kind
from tsdb_service.core.query import AggrMethod, AggrPeriod
from tsdb_service.core.timefmt import iso_ms_us

HOUR_US = 3_600_000_000
_NULL, _NUMBER, _INTEGER = int(Kind.NULL), int(Kind.NUMBER), int(Kind.INTEGER)
# Periods made of whole hours, the only ones partials can answer.
PERIODS = frozenset({AggrPeriod.HOUR, AggrPeriod.DAY, AggrPeriod.MONTH, AggrPeriod.YEAR})
_MAX_PARTS = 8  # an hour's sum list is compressed back to its exact minimum beyond this
# A load brings each hour's numbers into Python once (for the exact sum):
# above this many samples the window is aggregated by SQL instead.
MAX_LOAD_SAMPLES = 1_000_000

# A cell: one series' hour. SUM, ALL_INT and ISO are derived (kept so that
# answering an hourly aggregation is a slice of ready values), NOTHING is None.
PRESENT, NUMERIC, INTEGERS, PARTS, MIN, MAX, T_MIN, T_MAX, SUM, ALL_INT, ISO, NOTHING = range(12)
# The cell slot holding SQL's ``value`` for each method.
VALUE_SLOT = {
    AggrMethod.SUM: SUM,
    AggrMethod.AVG: SUM,
    AggrMethod.MIN: MIN,
    AggrMethod.MAX: MAX,
    AggrMethod.COUNT: NOTHING,
}
_ISO: dict[int, str] = {}  # hour µs -> its ISO text, shared by every series' cells


def hour_iso(hour: int) -> str:
    """``hour`` as SQL formats a bucket, one string per hour for all series."""
    text = _ISO.get(hour)
    if text is None:
        if len(_ISO) > 100_000:
            _ISO.clear()
        text = _ISO[hour] = iso_ms_us(hour)
    return text


def new_cell(hour: int, present: int, numeric: int, integers: int, parts: list[float], mn, mx, t0: int, t1: int):
    """A cell and its derived slots."""
    cell = [present, numeric, integers, parts, mn, mx, t0, t1, None, None, hour_iso(hour), None]
    _derive(cell)
    return cell


def _derive(cell: list) -> None:
    numeric = cell[NUMERIC]
    cell[SUM] = math.fsum(cell[PARTS]) if numeric else None
    cell[ALL_INT] = cell[INTEGERS] == numeric if numeric else None


# Load rows: (sid, hour µs, n_present, n_numeric, n_integer, [numbers], min, max, t_min µs, t_max µs, max rid)
LoadRow = tuple


def exact_parts(values: list[float]) -> list[float]:
    """Floats whose exact sum equals the exact sum of ``values``, largest
    first: each is the correctly rounded remainder of the ones before (so
    ``math.fsum`` of the result, alone or with others, is exact). Usually one
    float, at most a few (each step gains 53 bits)."""
    parts: list[float] = []
    rest = math.fsum(values)
    while rest != 0.0:
        parts.append(rest)
        rest = math.fsum([*values, *(-p for p in parts)])
    return parts


class _Series:
    __slots__ = ("cells", "hours", "lo", "seen_rid", "version")

    def __init__(self, lo: int | None, seen_rid: int, version: object = None):
        self.lo = lo  # every sample at or after this hour is counted (None: all)
        self.seen_rid = seen_rid  # rows up to this id were in the load's snapshot
        self.version = version  # the database's change count when loaded (``series(versions=...)``)
        self.hours: list[int] = []  # sorted hour starts (µs)
        self.cells: list[list] = []

    def add(self, t: int, kind: int, num: float | None) -> None:
        """One committed sample (at or after ``lo``). Copy on write: a reader
        holding a cell (``HourlyPartials.window``) never sees it half updated."""
        hour = t - t % HOUR_US
        hours = self.hours
        at = len(hours)
        if not hours or hours[-1] != hour:
            at = bisect.bisect_left(hours, hour)
            if at == len(hours) or hours[at] != hour:
                hours.insert(at, hour)
                self.cells.insert(at, new_cell(hour, 0, 0, 0, [], None, None, t, t))
        else:
            at -= 1
        cell = list(self.cells[at])
        self._count(cell, t, kind, num)
        self.cells[at] = cell

    @staticmethod
    def _count(cell: list, t: int, kind: int, num: float | None) -> None:
        if kind != _NULL:
            cell[PRESENT] += 1
        if num is not None and kind in (_NUMBER, _INTEGER):
            cell[NUMERIC] += 1
            if kind == _INTEGER:
                cell[INTEGERS] += 1
            parts = [*cell[PARTS], num]
            cell[PARTS] = exact_parts(parts) if len(parts) > _MAX_PARTS else parts
            cell[MIN] = num if cell[MIN] is None or num < cell[MIN] else cell[MIN]
            cell[MAX] = num if cell[MAX] is None or num > cell[MAX] else cell[MAX]
            _derive(cell)
        if t < cell[T_MIN]:
            cell[T_MIN] = t
        if t > cell[T_MAX]:
            cell[T_MAX] = t


class _Load:
    """A load in flight: the writer's publishes for its series, buffered."""

    __slots__ = ("buffer", "sids", "voided")

    def __init__(self, sids: Iterable[int]):
        self.sids = set(sids)
        self.buffer: list[tuple[int, int, int, int, float | None]] = []  # (sid, rid, t, kind, num)
        self.voided: set[int] = set()


class HourlyPartials:
    def __init__(self, max_hours: int = 100_000):
        """At most ``max_hours`` series-hours in all (about 400 bytes each);
        0 turns partials off."""
        self.max_hours = max_hours
        self._entries: OrderedDict[int, _Series] = OrderedDict()
        self._loads: list[_Load] = []
        self._total = 0
        self._lock = threading.Lock()
        self.hits = 0
        self.misses = 0

    @property
    def enabled(self) -> bool:
        return self.max_hours > 0

    @property
    def hours(self) -> int:
        """Series-hours held now (for tests and metrics)."""
        return self._total

    # -- writers -------------------------------------------------------------------

    def publish(self, cols: dict[str, list]) -> None:
        """Committed samples (the appender's columns) reach cached series."""
        if not self._entries and not self._loads:
            return
        with self._lock:
            entries, loads = self._entries, self._loads
            sids, rids, times, kinds, nums = cols["sid"], cols["rid"], cols["t"], cols["kind"], cols["num"]
            for i in range(len(sids)):
                sid = sids[i]
                for load in loads:
                    if sid in load.sids:
                        load.buffer.append((sid, rids[i], times[i], kinds[i], nums[i]))
                entry = entries.get(sid)
                if entry is not None and rids[i] > entry.seen_rid and (entry.lo is None or times[i] >= entry.lo):
                    before = len(entry.hours)
                    entry.add(times[i], kinds[i], nums[i])
                    self._total += len(entry.hours) - before
            self._evict()

    def drop(self, sids: Iterable[int]) -> None:
        """Forget series whose samples were deleted or changed."""
        with self._lock:
            for sid in sids:
                entry = self._entries.pop(sid, None)
                if entry is not None:
                    self._total -= len(entry.hours)
                for load in self._loads:
                    if sid in load.sids:
                        load.voided.add(sid)

    def clear(self) -> None:
        with self._lock:
            self._entries.clear()
            self._total = 0
            for load in self._loads:
                load.voided |= load.sids

    # -- readers -------------------------------------------------------------------

    def series(
        self,
        sids: Sequence[int],
        lo: int | None,
        load: Callable[[list[int], int | None], list[LoadRow] | None],
        versions: Mapping[int, object] | None = None,
    ) -> dict[int, _Series] | None:
        """Each series' entry covering every hour from ``lo`` on, loading the
        missing ones with one ``load(sids, lo)`` call; None when the load
        declines (too many samples: ``MAX_LOAD_SAMPLES``).

        ``versions``, where writes do not all pass through ``publish``
        (PostgreSQL: other sessions and replicas), is each series' change
        count read from the database before this call: an entry loaded at
        another count is loaded again, and loaded entries keep the count.
        A load sees at least what the count says (it reads later), so an
        entry is never older than its count; a newer one is only loaded
        again once more."""
        out: dict[int, _Series] = {}
        missing: list[int] = []
        with self._lock:
            for sid in sids:
                entry = self._entries.get(sid)
                if (
                    entry is not None
                    and (entry.lo is None or (lo is not None and entry.lo <= lo))
                    and (versions is None or entry.version == versions[sid])
                ):
                    self._entries.move_to_end(sid)
                    out[sid] = entry
                else:
                    missing.append(sid)
            if not missing:
                self.hits += 1
                return out
            self.misses += 1
            pending = _Load(missing)
            self._loads.append(pending)
        try:
            rows = load(missing, lo)
        finally:
            with self._lock:
                self._loads.remove(pending)
        if rows is None:
            return None
        loaded = _build(missing, rows, lo)
        if versions is not None:
            for sid, entry in loaded.items():
                entry.version = versions[sid]
        with self._lock:
            for sid, rid, t, kind, num in pending.buffer:
                entry = loaded[sid]
                if rid > entry.seen_rid and (lo is None or t >= lo):
                    entry.add(t, kind, num)
            for sid, entry in loaded.items():
                if sid not in pending.voided:
                    self._install(sid, entry)
            self._evict()
        out.update(loaded)
        return out

    def window(self, entry: _Series, lo: int | None, end: int | None) -> tuple[list[int], list[list]]:
        """The hours of ``entry`` from ``lo`` to ``end`` (µs, None: open) and
        their cells, taken together under the lock (a publish may insert
        hours meanwhile; cells are replaced, never changed in place)."""
        with self._lock:
            hours = entry.hours
            i = 0 if lo is None else bisect.bisect_left(hours, lo)
            j = len(hours) if end is None else bisect.bisect_right(hours, end)
            return hours[i:j], entry.cells[i:j]

    def _install(self, sid: int, entry: _Series) -> None:
        old = self._entries.pop(sid, None)
        if old is not None:
            self._total -= len(old.hours)
        if len(entry.hours) <= self.max_hours:
            self._entries[sid] = entry
            self._total += len(entry.hours)

    def _evict(self) -> None:
        while self._total > self.max_hours and self._entries:
            _, evicted = self._entries.popitem(last=False)
            self._total -= len(evicted.hours)


def _build(sids: Sequence[int], rows: list[LoadRow], lo: int | None) -> dict[int, _Series]:
    """Entries from a load's rows (ordered by series, then hour)."""
    entries = {sid: _Series(lo, -1) for sid in sids}
    for sid, hour, present, numeric, integers, numbers, mn, mx, t_min, t_max, max_rid in rows:
        entry = entries[sid]
        entry.hours.append(hour)
        entry.cells.append(new_cell(hour, present, numeric, integers, exact_parts(numbers or []), mn, mx, t_min, t_max))
        if max_rid > entry.seen_rid:
            entry.seen_rid = max_rid
    return entries


# -- answering ------------------------------------------------------------------------

_BUCKETS: dict[tuple[AggrPeriod | None, int], tuple[int, str | None]] = {}


def bucket_of(period: AggrPeriod | None, hour: int) -> tuple[int, str | None]:
    """(bucket start µs, ISO text as SQL formats it) of ``hour`` in ``period``;
    memoised (a few thousand distinct hours cover any dashboard)."""
    key = (period, hour)
    got = _BUCKETS.get(key)
    if got is None:
        if len(_BUCKETS) > 200_000:
            _BUCKETS.clear()
        start = _truncate(period, hour)
        got = _BUCKETS[key] = (start, None if period is None else iso_ms_us(start))
    return got


def _truncate(period: AggrPeriod | None, hour: int) -> int:
    if period is None:
        return 0
    if period is AggrPeriod.HOUR:
        return hour
    if period is AggrPeriod.DAY:
        return hour - hour % (24 * HOUR_US)
    moment = datetime.fromtimestamp(hour // 1_000_000, UTC)
    moment = moment.replace(day=1, hour=0) if period is AggrPeriod.MONTH else moment.replace(month=1, day=1, hour=0)
    return int(moment.timestamp()) * 1_000_000


class Accumulator:
    """One (series, bucket)'s partials while a request combines hours (and
    SQL's rows for cut hours): counts, the exact-sum list, min, max."""

    __slots__ = ("all_int", "maximum", "minimum", "numeric", "parts", "present")

    def __init__(self) -> None:
        self.present = 0
        self.numeric = 0
        self.all_int: bool | None = None
        self.parts: list[float] = []
        self.minimum: float | None = None
        self.maximum: float | None = None

    def add_cell(self, cell: list) -> None:
        self.present += cell[PRESENT]
        if cell[NUMERIC]:
            self._numbers(cell[NUMERIC], cell[INTEGERS] == cell[NUMERIC], cell[PARTS], cell[MIN], cell[MAX])

    def add_row(self, n_present: int, n_numeric: int, value, all_integer, method: AggrMethod) -> None:
        """A SQL row's partials (``AggregateRow`` fields) for the same bucket."""
        self.present += n_present
        if n_numeric:
            parts = [value] if value is not None and method in (AggrMethod.SUM, AggrMethod.AVG) else []
            mn = value if method is AggrMethod.MIN else None
            mx = value if method is AggrMethod.MAX else None
            self._numbers(n_numeric, bool(all_integer), parts, mn, mx)

    def _numbers(self, n: int, all_int: bool, parts: list[float], mn, mx) -> None:
        self.numeric += n
        self.all_int = all_int if self.all_int is None else (self.all_int and all_int)
        self.parts.extend(parts)
        if mn is not None and (self.minimum is None or mn < self.minimum):
            self.minimum = mn
        if mx is not None and (self.maximum is None or mx > self.maximum):
            self.maximum = mx

    def value(self, method: AggrMethod) -> float | None:
        """The row's ``value`` as SQL defines it for ``method``."""
        if not self.numeric:
            return None
        if method is AggrMethod.SUM or method is AggrMethod.AVG:
            return math.fsum(self.parts)
        if method is AggrMethod.MIN:
            return self.minimum
        if method is AggrMethod.MAX:
            return self.maximum
        return None
