"""The newest samples of recently read series, in memory (DuckDB only).

"The latest N values of this attribute" is the most common history request
and the one dashboards repeat. From the database it costs a query of about a
millisecond however small the answer; from here, a slice of a list. Like
Prometheus' head block, the tail holds the newest samples of a series:

* loaded on the first read of a series (its newest ``rows`` samples);
* kept current by the writers, which publish every committed sample of a
  cached series, in time order (late samples are inserted where they belong);
* dropped for series touched by a delete.

A load races the writers: a commit between the load's query and its
install could be missing from it. Every publish bumps a sequence number; a
load installs only if the number did not move while it ran, otherwise it
answers from its own query and leaves the cache alone. Publishing skips a
row the entry already holds, so a commit seen by a load and published later
is not counted twice.

An entry answers a request only when that is provably the same as asking
the database: when it holds every sample of the series, or when at least
``offset + limit`` of its samples lie in the requested time window (any
sample not cached is older than all cached ones).

On PostgreSQL several replicas write, so no process sees every commit; the
(sid, t) index serves these requests there instead.
"""

from __future__ import annotations

import bisect
import threading
from collections import OrderedDict
from collections.abc import Callable

from tsdb_service.core.timefmt import iso_ms_us as iso_ms

# (t in epoch µs, rid, ISO time, kind, num, txt, js); sorted by (t, rid)
TailRow = tuple[int, int, str, int, float | None, str | None, str | None]


class _Entry:
    __slots__ = ("keys", "rows", "whole")

    def __init__(self, rows: list[TailRow], whole: bool):
        self.rows = rows
        self.keys = [(r[0], r[1]) for r in rows]
        self.whole = whole  # holds every sample of the series


class TailCache:
    def __init__(self, max_series: int = 4096, rows: int = 128, max_rows: int | None = None):
        """At most ``rows`` samples per series; at most ``max_rows`` samples in
        all (default ``max_series * rows``), least recently read series first
        out. Memory is about 200 bytes per cached sample."""
        self.max_series = max_series
        self.capacity = rows
        self.max_rows = max_rows if max_rows is not None else max_series * rows
        self._total = 0
        self._entries: OrderedDict[int, _Entry] = OrderedDict()
        self._lock = threading.Lock()
        self._seq = 0
        self.hits = 0
        self.misses = 0

    @property
    def enabled(self) -> bool:
        return self.max_series > 0 and self.capacity > 0

    # -- writers -----------------------------------------------------------------

    def publish(self, cols: dict[str, list]) -> None:
        """Committed samples (the appender's columns) reach cached series."""
        if not self.enabled:
            return
        with self._lock:
            self._seq += 1
            entries = self._entries
            if not entries:
                return
            sids = cols["sid"]
            for i in range(len(sids)):
                entry = entries.get(sids[i])
                if entry is not None:
                    self._insert(entry, cols, i)

    def _insert(self, entry: _Entry, cols: dict[str, list], i: int) -> None:
        key = (cols["t"][i], cols["rid"][i])
        if not entry.whole and entry.keys and key < entry.keys[0]:
            return  # older than the tail: not part of it
        at = bisect.bisect_left(entry.keys, key)
        if at < len(entry.keys) and entry.keys[at] == key:
            return  # already loaded with the tail
        row = (key[0], key[1], iso_ms(key[0]), cols["kind"][i], cols["num"][i], cols["txt"][i], cols["js"][i])
        entry.keys.insert(at, key)
        entry.rows.insert(at, row)
        self._total += 1
        if len(entry.rows) > self.capacity:
            del entry.keys[0], entry.rows[0]
            entry.whole = False
            self._total -= 1

    def drop(self, sids) -> None:
        """Forget series whose samples were deleted."""
        with self._lock:
            self._seq += 1
            for sid in sids:
                entry = self._entries.pop(sid, None)
                if entry is not None:
                    self._total -= len(entry.rows)

    # -- readers -----------------------------------------------------------------

    def rows(
        self,
        sid: int,
        load: Callable[[int, int], list[TailRow]],
        start_us: int | None,
        end_us: int | None,
        newest_first: bool,
        limit: int,
        offset: int,
    ) -> list[TailRow] | None:
        """The rows SQL would return, oldest first, or None when the tail
        cannot know them (the caller then asks the database)."""
        if not self.enabled or offset + limit > self.capacity:
            return None
        with self._lock:
            entry = self._entries.get(sid)
            if entry is not None:
                self._entries.move_to_end(sid)
            seq = self._seq
        if entry is None:
            self.misses += 1
            entry = self._load(sid, load, seq)
        else:
            self.hits += 1
        with self._lock:
            return _answer(entry, start_us, end_us, newest_first, limit, offset)

    def _load(self, sid: int, load, seq: int) -> _Entry:
        entry = self._entry(load(sid, self.capacity + 1))
        with self._lock:
            self._install_locked({sid: entry}, seq)
        return entry

    def _entry(self, newest: list[TailRow]) -> _Entry:
        """A tail from a series' newest ``capacity + 1`` rows, newest first."""
        return _Entry(newest[: self.capacity][::-1], len(newest) <= self.capacity)

    def _install_locked(self, entries: dict[int, _Entry], seq: int) -> None:
        """Keep loaded tails unless a publish or drop raced the load (``seq``
        moved), oldest used out first past ``max_rows``. Caller holds the lock."""
        if self._seq != seq:
            return
        for sid, entry in entries.items():
            if sid not in self._entries:
                self._entries[sid] = entry
                self._total += len(entry.rows)
        while self._total > self.max_rows and len(self._entries) > 1:
            _, evicted = self._entries.popitem(last=False)
            self._total -= len(evicted.rows)

    def newest_many(
        self, sids: list[int], load: Callable[[list[int], int], dict[int, list[TailRow]]], start_us, end_us
    ) -> dict[int, list[TailRow] | None]:
        """For series not cached, what ``rows(sid, ..., newest_first=True,
        limit=capacity, offset=0)`` returns, from one ``load(sids, n)``
        (per series its newest ``n`` rows, newest first) instead of one load
        each. The tails are installed as ``rows`` would (not when a publish
        raced the load); either way the loaded rows answer."""
        if not self.enabled or not sids:
            return {}
        with self._lock:
            seq = self._seq
        newest = load(sids, self.capacity + 1)
        entries = {sid: self._entry(newest.get(sid, [])) for sid in sids}
        self.misses += len(sids)
        with self._lock:
            self._install_locked(entries, seq)
            return {sid: _answer(entry, start_us, end_us, True, self.capacity, 0) for sid, entry in entries.items()}


def _answer(entry: _Entry, start_us, end_us, newest_first: bool, limit: int, offset: int):
    rows = entry.rows
    lo = 0 if start_us is None else bisect.bisect_left(entry.keys, (start_us, -1))
    hi = len(rows) if end_us is None else bisect.bisect_right(entry.keys, (end_us, 2**63))
    in_window = hi - lo
    if not entry.whole and (not newest_first or in_window < offset + limit):
        return None
    if newest_first:
        stop = hi - offset
        return rows[max(lo, stop - limit) : max(lo, stop)]
    first = lo + offset
    return rows[first : min(hi, first + limit)]
