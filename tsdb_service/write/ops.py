"""What a write asks of the store: one frozen operation per change.

Every write, whoever makes it (a notification, an NGSI-LD temporal write, a
copy, a delete route), becomes one of these values and goes to the store's
writer (``write.Writer``). A group commit stages many of them in one
transaction; each backend's appender knows how to stage each kind.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from datetime import datetime

from tsdb_service.core.model import AttrSample, EntitySample, RejectedNotification
from tsdb_service.parse import ValuesLayout


@dataclass(frozen=True, slots=True)
class AppendSamples:
    """Store samples. ``dedup``: drop NGSI-LD instances that repeat their
    series' latest stored one (see ``storage.ld_ingest``); off for copies,
    which must reproduce the source exactly."""

    entities: Sequence[EntitySample]
    dedup: bool = True


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


@dataclass(frozen=True, slots=True)
class DeleteInstance:
    """Delete one NGSI-LD attribute instance (sample ``iid`` of series ``sid``)."""

    sid: int
    iid: int


@dataclass(frozen=True, slots=True)
class ReplaceInstance:
    """Replace the content of one NGSI-LD attribute instance in place: its
    instance id, series and row time stay; value, type, sub-properties and
    observedAt become ``attr``'s (observedAt only when ``attr`` has one),
    and ``modified_at`` is set."""

    sid: int
    iid: int
    attr: AttrSample
    modified_at: datetime


WriteOp = AppendSamples | RecordRejected | PutLayout | DeleteSamples | DeleteInstance | ReplaceInstance
