"""The series that hold NGSI-LD instances without an observedAt, kept in
PostgreSQL (``untimed_series``, migration 0009).

A window on observedAt reads an instance by its observedAt, or by its row
time when it has none. Those are two index scans per selected series
(``storage.sql.temporal.window_filter``); the second finds nothing for series
whose instances all carry observedAt, yet costs as much as the first. Readers
ask this table which of their series can have such instances and scan the
row time only for those (``PostgresQuerier._untimed``).

The writers add a series in the transaction that stores its first instance
without observedAt, before the samples (in the autocommit path, in its own
statement just before the COPY: a listed series without such instances only
costs a scan, a missing one would lose instances from windows). Entries are
never removed. Each process remembers the series it has listed, so NGSIv2
ingest of known series sends no statement.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Mapping, Sequence

from tsdb_service.core.model import EntitySample
from tsdb_service.storage.postgres.ids import SeriesKey

INSERT = (
    "INSERT INTO untimed_series (sid) "
    "SELECT s.sid FROM unnest(%s::text[], %s::text[], %s::text[], %s::text[], %s::text[]) "
    "AS b(tenant, service_path, entity_id, entity_type, attr) "
    "JOIN series s USING (tenant, service_path, entity_id, entity_type, attr) ORDER BY s.sid "
    "ON CONFLICT (sid) DO NOTHING"
)

# What ``record`` returns: call it with the batch's series ids once committed.
Committed = Callable[[Mapping[SeriesKey, int]], None]


def _nothing(ids: Mapping[SeriesKey, int]) -> None:
    return None


class UntimedLedger:
    """The series this process knows are listed in ``untimed_series``."""

    def __init__(self, sid_of: Callable[[SeriesKey], int | None]) -> None:
        self._sid_of = sid_of  # the store's committed series' ids (``ids.PostgresIds.sid_of``)
        self._known: set[int] = set()
        self._lock = threading.Lock()

    def record(self, cur, entities: Sequence[EntitySample]) -> Committed:
        """List (with ``cur``, before the batch's samples) the series the
        batch gives an instance without observedAt, unless known listed.
        Returns what to call, with the batch's series ids (new series'
        too), once that committed."""
        sid_of, known = self._sid_of, self._known
        new: dict[SeriesKey, None] = {}
        for e in entities:
            prefix = (e.tenant, e.service_path, e.entity_id, e.entity_type)
            for a in e.attrs:
                if a.observed_at is None:
                    key = (*prefix, a.name)
                    if sid_of(key) not in known:
                        new[key] = None
        if not new:
            return _nothing

        cur.execute(INSERT, [list(col) for col in zip(*new, strict=True)])

        def committed(ids: Mapping[SeriesKey, int]) -> None:
            listed = {ids[key] for key in new if key in ids}
            with self._lock:
                known.update(listed)

        return committed
