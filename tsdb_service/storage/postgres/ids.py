"""The ids PostgreSQL's writers use: series ids this process knows, row ids.

One owner, shared by the store (its queriers count the series), its writers
and the untimed-series ledger (``untimed``).

* **Series ids** come from the ``series`` table, shared by every replica
  (insert-if-absent, then read back: ``appender``). This process remembers
  the ones it has seen committed, so known series cost no statement; a key
  enters only after the transaction that inserted or read it committed
  (``publish_series``): a rolled-back series row would orphan samples.
* **Row ids** (``rid``, one per entity sample) are handed out in order from
  blocks reserved from ``sample_rid_seq`` (``RowIds``).
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Mapping

SeriesKey = tuple[str, str, str, str, str]  # tenant, service path, entity id, entity type, attr


class RowIds:
    """Row ids (``rid``, one per entity sample) handed out in order from
    blocks reserved from ``sample_rid_seq``: one ``nextval`` round trip per
    ``block`` ids instead of one per group. Ids are unique across replicas
    (the sequence) and, within this process, increase in the order groups
    take them, as when each group called ``nextval`` itself (reads order
    samples of one instant by rid). Unused ids of a block are gaps, which a
    sequence has anyway."""

    def __init__(self, block: int = 1024):
        self.block = block
        self._free: list[int] = []
        self._lock = threading.Lock()

    def take(self, n: int, reserve: Callable[[int], list[int]]) -> list[int]:
        """``n`` ids; ``reserve(k)`` fetches k new ones from the sequence
        (under the lock, so blocks are appended in sequence order)."""
        with self._lock:
            free = self._free
            if len(free) < n:
                free.extend(reserve(max(self.block, n - len(free))))
            taken = free[:n]
            del free[:n]
            return taken


class PostgresIds:
    """Series ids this process knows committed, and its row-id blocks."""

    def __init__(self, row_block: int = 1024) -> None:
        self._series: dict[SeriesKey, int] = {}  # written by the writers after commit; readers take no lock
        self._rows = RowIds(row_block)

    def sid_of(self, key: SeriesKey) -> int | None:
        """A series' id, if this process has seen it committed."""
        return self._series.get(key)

    def series_count(self) -> int:
        """Series this process's writers created or read back (grows only)."""
        return len(self._series)

    def publish_series(self, found: Mapping[SeriesKey, int]) -> None:
        """After the commit of the transaction that inserted or read ``found``."""
        self._series.update(found)

    def take_rids(self, n: int, reserve: Callable[[int], list[int]]) -> list[int]:
        """``n`` row ids, in order (``RowIds.take``)."""
        return self._rows.take(n, reserve)
