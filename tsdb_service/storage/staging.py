"""The shape both backends' writers share (``duckdb.appender``, ``postgres.appender``).

A writer belongs to one writer thread of the group committer
(``write.committer``) and is never shared. For each group it:

1. **stages** the operations (``stage``: one ``_stage_*`` or list per kind;
   no database write yet);
2. **commits** them in as few transactions as it can (``commit`` →
   ``_commit``), telling the store whether the database took the write
   (``note_write``, for ``/health``), and raises, leaving nothing, when it
   did not;
3. **publishes** to the store's memory what each transaction made true,
   right after that transaction: never before, so memory is never ahead of
   the database (``_publish`` for what the group's last one made true).

A writer reaches its store through a small protocol of public names
(``WriteTarget``, which each backend extends): the store's ``ids`` (series
and row ids), its ``memory`` (what reads answer from), the rejected store's
bounds and drop counters, and ``note_write``. It reaches no private name of
the store.
"""

from __future__ import annotations

from abc import abstractmethod
from collections.abc import Sequence
from typing import Protocol

from tsdb_service.core.model import EntitySample, RejectedNotification
from tsdb_service.storage.rejected import RejectedLimits
from tsdb_service.write.appender import Appender
from tsdb_service.write.ops import (
    AppendSamples,
    DeleteInstance,
    DeleteSamples,
    Delivery,
    LogPosition,
    PutLayout,
    RecordDelivery,
    RecordRejected,
    ReplaceInstance,
    WriteOp,
)


class WriteTarget(Protocol):
    """What every writer needs of its store, besides its backend's ``ids``,
    ``memory`` and connection (each backend's protocol adds those)."""

    rejected_limits: RejectedLimits  # bounds pruned in the transaction that records a rejection
    rejected_dropped: dict[str, int]  # what pruning dropped, by reason (``rejected.count_dropped``)

    def note_write(self, exc: BaseException | None) -> None:
        """After each commit: None when it went through, else its error."""
        ...


class StagingAppender(Appender):
    """The dispatch over ``WriteOp`` types; a backend stages each kind."""

    _layouts: list[PutLayout]
    _instance_ops: list[DeleteInstance | ReplaceInstance]
    _deliveries: list[Delivery]  # committed with the samples or rejections staged beside them

    def stage(self, op: WriteOp) -> None:
        if isinstance(op, AppendSamples):
            self._stage_samples(op.entities, op.dedup)
            self._deliveries.extend(op.deliveries)
            if op.log_position is not None:
                self._stage_log_position(op.log_position)
        elif isinstance(op, RecordRejected):
            self._stage_rejected(op.rejected)
            if op.delivery is not None:
                self._deliveries.append(op.delivery)
        elif isinstance(op, RecordDelivery):
            self._deliveries.append(op.delivery)
        elif isinstance(op, PutLayout):
            self._layouts.append(op)
        elif isinstance(op, DeleteSamples):
            self._stage_delete(op)
        elif isinstance(op, (DeleteInstance, ReplaceInstance)):
            self._instance_ops.append(op)
        else:  # pragma: no cover - programming error
            raise TypeError(f"unknown write op {op!r}")

    @abstractmethod
    def _stage_samples(self, entities: Sequence[EntitySample], dedup: bool) -> None: ...

    @abstractmethod
    def _stage_rejected(self, r: RejectedNotification) -> None: ...

    @abstractmethod
    def _stage_delete(self, op: DeleteSamples) -> None: ...

    def _stage_log_position(self, position: LogPosition) -> None:
        """Record ``position`` with the samples staged beside it: only a
        backend with an ingest log (DuckDB) has one to record."""
        raise TypeError(f"{type(self).__name__} keeps no ingest log: {position!r}")

    @abstractmethod
    def _publish(self) -> None:
        """After the group's last commit: publish what it made true, then ``_reset``."""

    @abstractmethod
    def _reset(self) -> None:
        """Forget everything staged (after a commit, or a rollback)."""
