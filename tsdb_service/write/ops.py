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
class Delivery:
    """The identity of one MQTT message (``ingest.mqtt``), stored in the same
    transaction as what the message stored, so that a broker's redelivery of
    a message already stored can be told (migration 0012). ``prune_below``:
    also forget this client's deliveries numbered below it (0: none)."""

    client_id: str
    seq: int
    packet_id: int
    digest: bytes
    received_at: datetime
    prune_below: int = 0


@dataclass(frozen=True, slots=True)
class LogPosition:
    """How much of the ingest log (``write.logged``) a database holds: every
    record up to sequence number ``seq``, and every entity up to row id
    ``rid`` (row ids follow log order; an entity applied alone past ``seq``
    moves ``rid`` only)."""

    seq: int
    rid: int


@dataclass(frozen=True, slots=True)
class AppendSamples:
    """Store samples. ``dedup``: drop NGSI-LD instances that repeat their
    series' latest stored one (see ``storage.ld_ingest``); off for copies,
    which must reproduce the source exactly. ``deliveries``: the MQTT
    messages these samples came from, recorded atomically with them.
    ``log_position``: the ingest log's applier says what these samples
    complete; the writer records it in the same transaction (DuckDB)."""

    entities: Sequence[EntitySample]
    dedup: bool = True
    deliveries: tuple[Delivery, ...] = ()
    log_position: LogPosition | None = None


@dataclass(frozen=True, slots=True)
class RecordRejected:
    """Keep a refused notification; ``delivery``: the MQTT message it was,
    recorded atomically with it."""

    rejected: RejectedNotification
    delivery: Delivery | None = None


@dataclass(frozen=True, slots=True)
class RecordDelivery:
    """Record an MQTT delivery that stores nothing else: the consumer's mark
    of a new broker session, whose ``prune_below`` forgets every earlier
    delivery of its client id (``ingest.mqtt``). Not a sample write, so it
    never goes through the ingest log."""

    delivery: Delivery


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


WriteOp = AppendSamples | RecordRejected | RecordDelivery | PutLayout | DeleteSamples | DeleteInstance | ReplaceInstance
