"""Rebuilding and checking rollups over a store's series (``tsdb-service rollups``).

The commands pick the series (every tenant, or one; every entity type, or
one) through the read seam and hand them to ``storage.rollup_repair``,
which does the work in the database. ``rebuild`` recomputes what raw
samples can still answer for and keeps what only rollups hold (unless
asked to drop it); ``check`` compares a random sample of buckets with raw.
"""

from __future__ import annotations

from collections.abc import Callable
from datetime import datetime

from tsdb_service.core.query import EntityFilter, Scope, TimeRange
from tsdb_service.read.requests import SeriesSelect
from tsdb_service.storage.rollup_repair import CheckReport, RebuildReport, check, rebuild
from tsdb_service.storage.store import Store


def selected_series(store: Store, tenant: str | None, entity_type: str | None) -> list[int]:
    """The series of ``tenant`` (None: every tenant) and ``entity_type``
    (None: every type), by id."""
    querier = store.querier()
    tenants = querier.tenants() if tenant is None else [tenant]
    entities = EntityFilter(types=(entity_type,) if entity_type is not None else None)
    return sorted(ref.sid for name in tenants for ref in querier.series(SeriesSelect(Scope(name), entities)))


def rebuild_rollups(
    store: Store,
    tenant: str | None = None,
    entity_type: str | None = None,
    start: datetime | None = None,
    end: datetime | None = None,
    *,
    drop_expired: bool = False,
    progress: Callable[[RebuildReport], None] | None = None,
) -> RebuildReport:
    """Recompute the selected series' rollups in [start, end) (None: open)."""
    sids = selected_series(store, tenant, entity_type)
    return rebuild(store, sids, _window(start, end), drop_expired=drop_expired, progress=progress)


def check_rollups(
    store: Store,
    tenant: str | None = None,
    entity_type: str | None = None,
    start: datetime | None = None,
    end: datetime | None = None,
    *,
    samples: int = 1000,
    seed: int | None = None,
) -> CheckReport:
    """Compare about ``samples`` buckets of the selected series with raw."""
    sids = selected_series(store, tenant, entity_type)
    return check(store, sids, _window(start, end), samples=samples, seed=seed)


def _window(start: datetime | None, end: datetime | None) -> TimeRange:
    """[start, end) as the inclusive range the storage layer takes."""
    from datetime import timedelta

    return TimeRange(start, None if end is None else end - timedelta(microseconds=1))
