"""The ids DuckDB's writers hand out: series, rows, instances, rejections.

One owner for them all, shared by the store (which loads them from the
file), its writers (which allocate them) and the ingest log (which gives
each acknowledged entity its row id, ``write.logged``).

Invariants:

* **Ids only grow, and are never handed out twice.** ``load`` (at open, and
  after a reopen) never moves a counter below an id already handed out.
* **One id per series key**, whichever writer meets the key first: an id
  not yet committed is *pending*, and every writer staging that key uses it.
  Each writer that staged it inserts the series row (skipping a key another
  writer committed meanwhile, ``commit_series``), so no sample can outlive a
  failed series insert; a rolled-back group leaves its ids pending for the
  next writer that meets the key.
* **The series map holds committed series only**: a key enters it after
  its row is durable (``commit_series``), so ``series_count`` (the catalog's
  generation) moves only then.

Locks: ``_alloc_lock`` around every counter and the two maps (short, no
I/O); ``_series_lock`` held across the series INSERT, so one writer at a
time inserts series rows.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Sequence

from tsdb_service.core.model import EntitySample

SeriesKey = tuple[str, str, str, str, str]  # tenant, service path, id, type, attr


class SeriesIds:
    """Every id a DuckDB writer hands out; see the module docstring."""

    def __init__(self) -> None:
        self._series: dict[SeriesKey, int] = {}
        self._pending_series: dict[SeriesKey, int] = {}
        self._next_sid = self._next_rid = self._next_iid = self._next_rejected = 1
        self._alloc_lock = threading.Lock()
        self._series_lock = threading.Lock()

    def load(self, series: dict[SeriesKey, int], max_rid: int, max_iid: int, max_rejected: int) -> None:
        """What the file holds: its series, and the largest ids it stored."""
        with self._alloc_lock:
            self._series = series
            self._next_sid = max(self._next_sid, max(series.values(), default=0) + 1)
            self._next_rid = max(self._next_rid, max_rid + 1)
            self._next_iid = max(self._next_iid, max_iid + 1)
            self._next_rejected = max(self._next_rejected, max_rejected + 1)

    # -- series ----------------------------------------------------------------------

    def sid_of(self, key: SeriesKey) -> int | None:
        """A committed series' id; None for a key not committed (yet)."""
        return self._series.get(key)

    def series_count(self) -> int:
        """Committed series: grows whenever a writer commits new ones."""
        return len(self._series)

    def allocate(self, entities: Sequence[EntitySample], new: dict[SeriesKey, int]) -> tuple[list[int], list[int], int]:
        """The ids a group's ``entities`` take, in one go: a row id per entity
        (its own when the ingest log gave it one), a series id per attribute,
        and the first of consecutive instance ids, one per attribute. Series
        not committed yet are added to ``new`` (the writer's, for
        ``commit_series``)."""
        rids: list[int] = []
        sids: list[int] = []
        with self._alloc_lock:
            series, pending = self._series, self._pending_series
            for entity in entities:
                rid = entity.rid
                if rid is None:
                    rid = self._next_rid
                    self._next_rid += 1
                rids.append(rid)
                prefix = (entity.tenant, entity.service_path, entity.entity_id, entity.entity_type)
                for attr in entity.attrs:
                    key = (*prefix, attr.name)
                    sid = series.get(key)
                    if sid is None:
                        sid = new.get(key)
                        if sid is None:
                            sid = pending.get(key)
                            if sid is None:
                                sid = pending[key] = self._next_sid
                                self._next_sid += 1
                            new[key] = sid
                    sids.append(sid)
            first_iid = self._next_iid
            self._next_iid += len(sids)
        return rids, sids, first_iid

    def commit_series(self, new: dict[SeriesKey, int], insert: Callable[[list[SeriesKey]], None]) -> None:
        """Make a writer's ``new`` series durable: ``insert(keys)`` writes the
        rows of those no other writer committed meanwhile (one writer at a
        time: a plain INSERT that cannot conflict; OR IGNORE is several times
        slower in DuckDB), then they are committed series."""
        with self._series_lock:
            keys = [k for k in new if k not in self._series]
            if keys:
                insert(keys)
            with self._alloc_lock:
                self._series.update(new)
                for key in new:
                    self._pending_series.pop(key, None)

    # -- rows, rejections ------------------------------------------------------------

    def take_rids(self, n: int) -> int:
        """The first of ``n`` consecutive row ids (the ingest log's)."""
        with self._alloc_lock:
            first = self._next_rid
            self._next_rid += n
        return first

    def saw_rid(self, rid: int) -> None:
        """``rid`` was handed out before (the ingest log's records): never again."""
        with self._alloc_lock:
            self._next_rid = max(self._next_rid, rid + 1)

    def newest_rid(self) -> int:
        """The largest row id handed out so far: rows above it are newer than now."""
        return self._next_rid - 1

    def rejected_id(self) -> int:
        """A new ``rejected_notifications`` id."""
        with self._alloc_lock:
            rejected_id = self._next_rejected
            self._next_rejected += 1
        return rejected_id
