"""Long windows: time buckets and state changes, computed by the database.

What every face that draws reads (Grafana's Infinity and SimpleJSON
endpoints, the explorer, ``export`` with a bucket width): a chart of a month
is a thousand buckets, never a million samples read into Python. The width
comes from ``core.buckets`` (round widths aligned to the epoch, so panels
refreshing every few seconds hit the same buckets).

* ``buckets(BucketRead)``: per series and bucket, the count, sum, minimum
  and maximum of its numeric samples and the first and last of them, each
  with its time, so the caller can draw the average, any one of them, or
  the min-max mode (first, min, max, last per bucket: a one-sample spike in a
  month still shows at 1,000 points). Only buckets holding at least one
  sample are returned; a missing bucket is a gap and the caller draws it as
  one. A backend answers wide buckets from its rollups (whole minutes, whole
  hours) and only the edges of the window from raw samples; the answer is
  exactly what the raw samples would give.
* ``state_changes(ChangesRead)``: the samples of non-numeric series (text,
  booleans, enumerations) whose value differs from the one before it, so a
  state timeline keeps every transition and nothing is ever averaged.
* ``span(SamplesIn)``: the first and last sample times of some series in a
  window, where a drawing's window has an open end (all data);
* ``count_up_to(SamplesIn, most)``: their samples in a window, counted no
  further than ``most`` (may they be drawn as stored?), and ``samples``:
  those samples, when they may (a direct read, times as integers).

Times are epoch microseconds (UTC) as plain integers: a 1,000-point panel
of 20 series is 20,000 rows of five times each, and making a ``datetime``
of each costs more than the database takes to compute them. A value path
(``steps``, as in ``core.query.ValuePath``) reads the number, or for
changes the value, at that path inside each stored JSON value.

Threads and lifetimes as for every read (``read``): any thread, never the
event loop, each call its own snapshot, rows owned by the caller.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from datetime import timedelta
from typing import NamedTuple, Protocol

from tsdb_service.core.query import TimeRange
from tsdb_service.read.requests import SamplesIn


@dataclass(frozen=True, slots=True)
class BucketRead:
    """Buckets of ``width`` (a ``core.buckets.LADDER`` width, aligned to the
    epoch) over ``time`` (both ends given, inclusive) of the series
    ``sids``. A bucket cut by an end of the window holds only the samples
    inside it. ``steps``: the numbers at this path inside JSON values (a
    ``ValuePath``'s steps) instead of the numeric samples themselves.
    ``extreme_times``: whether the times of the minimum and maximum are
    wanted (the min-max mode); without them a backend may answer ``min_t``
    and ``max_t`` as None, and finding them is most of the query's work."""

    sids: Sequence[int]
    time: TimeRange
    width: timedelta
    steps: tuple[str | int, ...] = ()
    extreme_times: bool = True


class BucketRow(NamedTuple):
    """One series' numeric samples in one bucket. ``n`` >= 1; the
    ``*_t`` are sample times (epoch µs, UTC); ties go to the earliest sample
    (then the lowest row id), for ``last`` to the latest."""

    sid: int
    start: int  # the bucket's start, epoch µs (not clipped to the window)
    n: int  # numeric samples
    total: float  # their sum
    all_integer: bool  # every one of them an integer
    min: float
    min_t: int | None  # None: not asked (``BucketRead.extreme_times``)
    max: float
    max_t: int | None
    first: float
    first_t: int
    last: float
    last_t: int


@dataclass(frozen=True, slots=True)
class ChangesRead:
    """Transitions of ``sids`` in ``time``: at most ``limit`` of them, the
    newest kept when there are more. ``steps``: compare the values at this
    path inside JSON values (a ``ValuePath``'s steps), not whole values."""

    sids: Sequence[int]
    time: TimeRange
    limit: int
    steps: tuple[str | int, ...] = ()


class StateChange(NamedTuple):
    """A sample whose value differs from the series' sample before it (the
    first sample of the window always counts). The value as stored (the
    whole value, also when changes are compared at a path). ``before``: the
    time of the series' sample before it in the window (None for the
    window's first), where the previous state was last seen: a run of
    states ends there (Grafana's annotations)."""

    sid: int
    time: int  # epoch µs
    kind: int
    num: float | None
    txt: str | None
    js: str | None
    before: int | None  # epoch µs


# One stored sample, its time as epoch µs (``BucketReader.samples``): (sid,
# time, kind, num, txt, js), a plain tuple as the driver hands it over
# (making 100,000 NamedTuples costs more than the read).
TimedSample = tuple[int, int, int, float | None, str | None, str | None]


class ChangesPage(NamedTuple):
    changes: list[StateChange]  # oldest first
    truncated: bool  # older transitions in the window were left out (``limit``)


class BucketReader(Protocol):
    def buckets(self, ask: BucketRead) -> list[BucketRow]:
        """Non-empty buckets of each series, by series then start."""
        ...

    def state_changes(self, ask: ChangesRead) -> ChangesPage:
        """Every transition of the series in the window (see ``ChangesRead``)."""
        ...

    def span(self, ask: SamplesIn) -> tuple[int, int] | None:
        """The first and last sample times (epoch µs) of ``ask.sids`` in
        ``ask.time`` (no mask); None when there is none. A backend keeping
        rollups counts the history they keep of samples retention deleted."""
        ...

    def count_up_to(self, ask: SamplesIn, most: int) -> int:
        """How many samples ``ask.sids`` hold in ``ask.time`` (no mask),
        counting no further than ``most``: whether a window's raw samples fit
        a point budget costs at most ``most`` rows read, however long it is.
        A backend keeping rollups answers ``most`` where the window holds
        history only they keep (raw samples cannot draw it whole)."""
        ...

    def samples(self, ask: SamplesIn, most: int) -> list[TimedSample]:
        """The samples of ``ask.sids`` in ``ask.time`` (no mask) by series,
        then time, then row id: the first ``most`` of them. For windows
        ``count_up_to`` found small: over a long one the ordering costs."""
        ...
