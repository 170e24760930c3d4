"""The storage seam: what routes may ask of a backend.

Modelled on Prometheus' storage interface: writes go through an *appender*
(stage a batch, then commit it atomically), reads through a *querier*. Routes
never see SQL; DuckDB and PostgreSQL each implement both halves.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import datetime
from typing import Any

from ..model import EntitySample, RejectedNotification
from ..ngsi import ValuesLayout


@dataclass(frozen=True, slots=True)
class AppendSamples:
    entities: Sequence[EntitySample]


@dataclass(frozen=True, slots=True)
class RecordRejected:
    rejected: RejectedNotification


@dataclass(frozen=True, slots=True)
class PutLayout:
    tenant: str
    subscription_id: str
    layout: ValuesLayout


@dataclass(frozen=True, slots=True)
class DeleteSamples:
    """Delete the samples of some series, optionally within a time range
    (inclusive, timezone-aware). Samples written after the delete was
    acknowledged are never touched. Series rows are kept."""

    sids: tuple[int, ...]
    start: datetime | None = None
    end: datetime | None = None


WriteOp = AppendSamples | RecordRejected | PutLayout | DeleteSamples


class Appender(ABC):
    """Stages write operations and commits them as one transaction.

    Owned by exactly one writer thread; never shared.
    """

    @abstractmethod
    def stage(self, op: WriteOp) -> None: ...

    @abstractmethod
    def commit(self) -> None:
        """Make everything staged durable, or raise and leave nothing."""

    @abstractmethod
    def rollback(self) -> None: ...

    def close(self) -> None:  # noqa: B027 - optional hook
        pass


class Querier(ABC):
    """The read half of the seam: history reads by series id.

    ``storage.sql.SqlQuerier`` implements it for SQL backends; row layouts
    are documented there. Thread-safe: routes call it from the threadpool.
    """

    @abstractmethod
    def series(self, scope, entities, attrs=None) -> list:
        """``SeriesRef``s of ``scope`` matching an ``EntityFilter`` and attribute names."""

    @abstractmethod
    def tenants(self) -> list[str]:
        """Every tenant with at least one series, sorted."""

    @abstractmethod
    def sids_with_samples(self, sids) -> set[int]: ...

    @abstractmethod
    def raw_rows(
        self, sids, time, *, newest_first: bool, limit: int, offset: int, one_per_row: bool, attrs_per_row: int = 1
    ) -> list[tuple]: ...

    @abstractmethod
    def aggregate(self, branches, time, agg) -> list[tuple]: ...

    @abstractmethod
    def latest_index(self, sids, time) -> list[tuple]: ...

    @abstractmethod
    def last_values(self, sids) -> list[tuple]: ...

    @abstractmethod
    def count(self, sids, time) -> int: ...

    @abstractmethod
    def latest_geometries(self, sids, time, prefilter) -> list[tuple]:
        """(sid, GeoJSON) of each series' latest geo sample, box-prefiltered."""


class Store(ABC):
    """A database with one writer and many readers."""

    backend: str
    # Retention and rollups (storage/retention.py): the background worker,
    # when a policy is set, and whether rollup rows may exist.
    retention = None
    rollup_presence = None

    def stop_retention(self) -> None:
        """Stop the retention worker (its batch in progress finishes first);
        ``close`` calls this before anything else."""
        if self.retention is not None:
            self.retention.stop()

    @abstractmethod
    async def write(self, op: WriteOp) -> None:
        """Queue ``op`` for the group committer; return once it is committed."""

    @abstractmethod
    def write_sync(self, ops: Sequence[WriteOp]) -> None:
        """Commit ops from a non-async caller (bulk loads, copy, tests)."""

    @abstractmethod
    def values_layout(self, tenant: str, subscription_id: str) -> ValuesLayout | None:
        """A registered ``values``-format layout, from memory (no I/O)."""

    @abstractmethod
    def layouts(self, tenant: str) -> dict[str, ValuesLayout]: ...

    @abstractmethod
    def rejected(self, tenant: str | None, limit: int, offset: int) -> list[dict[str, Any]]:
        """Rejected notifications of one tenant, newest first; ``None``: every
        tenant (the operator's listing)."""

    def rejected_page(self, tenant: str | None, limit: int, offset: int, max_bytes: int):
        """``rejected`` paged by rendered size too: ``(rows, next offset or
        None)``; at least one row, however big (``storage.rejected.page``)."""
        raise NotImplementedError

    @abstractmethod
    def health(self) -> dict[str, Any]: ...

    def querier(self) -> Querier:
        """The history reader (one per store, thread-safe)."""
        raise NotImplementedError(f"{type(self).__name__} has no history querier yet")

    @abstractmethod
    def close(self) -> None:
        """Drain queued writes, commit them, checkpoint, release the database."""
