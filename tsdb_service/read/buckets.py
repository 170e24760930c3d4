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

Threads and lifetimes as for every read (``read``): any thread, never the
event loop, each call its own snapshot, rows owned by the caller.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from datetime import datetime, timedelta
from typing import NamedTuple, Protocol

from tsdb_service.core.query import TimeRange


@dataclass(frozen=True, slots=True)
class BucketRead:
    """Buckets of ``width`` (a ``core.buckets.LADDER`` width, aligned to the
    epoch) over ``time`` (both ends given, inclusive) of the series
    ``sids``. A bucket cut by an end of the window holds only the samples
    inside it."""

    sids: Sequence[int]
    time: TimeRange
    width: timedelta


class BucketRow(NamedTuple):
    """One series' numeric samples in one bucket. ``n`` >= 1; the
    ``*_t`` are sample times (UTC, aware); ties go to the earliest sample
    (then the lowest row id), for ``last`` to the latest."""

    sid: int
    start: datetime  # the bucket's start (not clipped to the window)
    n: int  # numeric samples
    total: float  # their sum
    all_integer: bool  # every one of them an integer
    min: float
    min_t: datetime
    max: float
    max_t: datetime
    first: float
    first_t: datetime
    last: float
    last_t: datetime


@dataclass(frozen=True, slots=True)
class ChangesRead:
    """Transitions of ``sids`` in ``time``: at most ``limit`` of them, the
    newest kept when there are more."""

    sids: Sequence[int]
    time: TimeRange
    limit: int


class StateChange(NamedTuple):
    """A sample whose value differs from the series' sample before it (the
    first sample of the window always counts). The value as stored."""

    sid: int
    time: datetime
    kind: int
    num: float | None
    txt: str | None
    js: str | None


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
