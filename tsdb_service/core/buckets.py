"""Bucket widths for drawing a window with a point budget.

A chart of a long window is drawn from time buckets, one point (or four, in
the min-max mode) per bucket. The width is chosen from the window and the
point budget, then rounded *up* to a round width of ``LADDER`` (1 s, 10 s,
1 min, 5 min, 1 h, 1 d ...), and buckets start at multiples of the width
counted from the Unix epoch (UTC). So a panel that refreshes every few
seconds asks for the same buckets each time (their edges do not move with
``now``), the database's rollups (whole minutes, whole hours) line up with
them, and two panels of the same width agree.

Invariants:

* ``choose_width(span, points)`` is the narrowest ladder width that draws
  ``span`` in at most ``points`` buckets wherever the window lies (a window
  meets ``span // width + 1`` buckets at most, aligned as they are), and
  never narrower than a ``floor`` the client asked for (Grafana's
  ``intervalMs``); it depends on the span alone, so a panel sliding with
  ``now`` keeps its width;
* every width divides the next day boundary evenly up to one day
  (``bucket_start`` of a UTC midnight is that midnight), and a wider width is
  a whole number of days counted from the epoch;
* ``bucket_start(t, width) <= t < bucket_start(t, width) + width``.
"""

from __future__ import annotations

from datetime import UTC, datetime, timedelta

EPOCH = datetime(1970, 1, 1, tzinfo=UTC)

_MS = timedelta(milliseconds=1)
_S = timedelta(seconds=1)
_MIN = timedelta(minutes=1)
_H = timedelta(hours=1)
_D = timedelta(days=1)

LADDER: tuple[timedelta, ...] = (
    *(n * _MS for n in (1, 2, 5, 10, 20, 50, 100, 200, 500)),
    *(n * _S for n in (1, 2, 5, 10, 15, 30)),
    *(n * _MIN for n in (1, 2, 5, 10, 15, 30)),
    *(n * _H for n in (1, 2, 3, 6, 12)),
    *(n * _D for n in (1, 2, 7, 14, 30, 90, 365)),
)
WIDEST = LADDER[-1]

# Widths a level of rollups can serve: a bucket of such a width is a union of
# whole rollup buckets.
MINUTE = _MIN
HOUR = _H


def choose_width(span: timedelta, points: int, floor: timedelta | None = None) -> timedelta:
    """The narrowest ladder width drawing ``span`` in at most ``points``
    buckets wherever the window starts, at least ``floor`` (rounded up to
    the ladder)."""
    if points < 1:
        raise ValueError("a chart needs at least one point")
    wanted = span / points if span > timedelta(0) else LADDER[0]
    if floor is not None and floor > wanted:
        wanted = floor
    for width in LADDER:
        if width >= wanted and span // width + 1 <= points:
            return width
    return WIDEST


def epoch_micros(moment: datetime) -> int:
    """Exact microseconds since the epoch of an aware UTC ``moment`` (a float
    timestamp loses precision)."""
    return _micros(moment - EPOCH)


def bucket_start(moment: datetime, width: timedelta) -> datetime:
    """The start of the bucket of ``width`` holding ``moment`` (UTC, from the epoch)."""
    micros = _micros(moment - EPOCH)
    size = _micros(width)
    return EPOCH + timedelta(microseconds=micros - micros % size)


def bucket_count(start: datetime, end: datetime, width: timedelta) -> int:
    """How many buckets of ``width`` meet the inclusive window [start, end]."""
    return (_micros(bucket_start(end, width) - bucket_start(start, width)) // _micros(width)) + 1


def served_by(width: timedelta, level: timedelta) -> bool:
    """Whether buckets of ``width`` are unions of whole ``level`` buckets."""
    return width >= level and _micros(width) % _micros(level) == 0


def label(width: timedelta) -> str:
    """A width as people write it: ``500ms``, ``15s``, ``5min``, ``1h``, ``7d``."""
    micros = _micros(width)
    for unit, size in (("d", _D), ("h", _H), ("min", _MIN), ("s", _S), ("ms", _MS)):
        if micros % _micros(size) == 0:
            return f"{micros // _micros(size)}{unit}"
    return f"{micros}us"


def _micros(delta: timedelta) -> int:
    return (delta.days * 86_400 + delta.seconds) * 1_000_000 + delta.microseconds
