"""Acknowledge notifications on our own log; apply them to the database in bulk.

A database commit per group of notifications makes the commit, not the
notification, set the ingest rate (a DuckDB group commit costs about 3.7 ms
of CPU, whatever its size). So samples take two steps:

1. **Acknowledge.** A log writer thread (a ``GroupCommitter`` whose appender
   is the log) takes every queued ``AppendSamples``, gives each entity its row
   id, encodes the group (``write.codec``) and appends it to the ingest log
   (``write.log``) with one ``fdatasync``. Only then are the requests answered.
2. **Apply.** An applier thread hands the acknowledged entities to the
   store's own writer in batches of up to ``apply_rows`` samples: one
   database transaction per batch. Then the log's fully applied segments
   are deleted.

Invariants:

* **Nothing acknowledged is lost.** A group is acknowledged only after its
  record is durable; the database holds a prefix of the log (the applier
  applies in log order, a batch is one transaction); on start the records
  past what the database holds are applied again (``replay``).
* **Nothing is stored twice, nothing deleted comes back.** The database
  keeps the log position it holds (``LogPosition``: the last record applied,
  and the largest row id applied), written in the same transaction as each
  batch; a replay, and a retry after a failed or uncertain commit, apply
  exactly the records past it (``applied``). The largest row id left in the
  tables cannot say it: a delete removes rows. Deletes, instance edits and
  retention only touch rows a committed batch made, and its position came
  with it, so no replay brings their rows back.
* **Reads see every acknowledged write.** ``caught_up`` waits until
  everything acknowledged before it was called is applied; the store's
  ``read`` awaits it first. Under no load it costs nothing; under load, at
  most one apply cycle.
* **The log runs at most ``max_lag_bytes`` ahead of the database.** Past
  that the log writer waits for the applier (ingest slows, reads do not).
* **Other writes keep their order.** Deletes, rejected notifications,
  layouts and instance edits wait until everything acknowledged before them
  is applied (``barrier``), then go to the database writer directly.

Failure modes: the log cannot be written (disk full, a directory that is
not writable): the group gets 503 and nothing was stored, as before the
log, and ``problem`` says so (``/health`` fails) until a write succeeds. The database refuses a batch
(disk full, an invalidated DuckDB being reopened): the applier retries with
backoff, the log keeps the batch, ``/health`` fails with the reason, and
ingest slows to a stop at the lag bound. An entity the database refuses on
its own, again and again, is kept in the rejected store (it was parsed and
acknowledged, so this is a bug to report) and the rest goes on.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import threading
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from tsdb_service.core.errors import Unavailable
from tsdb_service.core.model import EntitySample
from tsdb_service.write import codec
from tsdb_service.write.appender import Appender
from tsdb_service.write.committer import CommitObserver, GroupCommitter, settle
from tsdb_service.write.log import QUARANTINE, IngestLog, LogError
from tsdb_service.write.ops import AppendSamples, LogPosition, WriteOp

log = logging.getLogger(__name__)

APPLY_ROWS = 50_000  # samples per database transaction, at most
# Encoded records acknowledged and not yet applied. 32 MiB since records of version 3
# (about 730 bytes a Lawnmower notification, 1,755 before): about as many
# notifications held in memory as 64 MiB of version 2 held.
MAX_LAG_BYTES = 32 * 1024 * 1024
RETRY_DELAY_S = 0.05
RETRY_MAX_DELAY_S = 5.0
POISON_ATTEMPTS = 5  # a lone entity refused this many times goes to the rejected store


@dataclass(slots=True)
class _Pending:
    seq: int
    op: AppendSamples
    nbytes: int
    samples: int


class LoggedWriter:
    """Samples through the ingest log; see the module docstring."""

    def __init__(
        self,
        log_: IngestLog,
        apply: Callable[[Sequence[WriteOp]], None],
        allocate_rids: Callable[[int], int],
        applied: Callable[[], LogPosition],
        reject: Callable[[EntitySample, str], None],
        *,
        healthy: Callable[[], bool] = lambda: True,
        seen_rid: Callable[[int], None] = lambda rid: None,
        apply_rows: int = APPLY_ROWS,
        max_lag_bytes: int = MAX_LAG_BYTES,
    ):
        self.log = log_
        self._apply = apply
        self._allocate_rids = allocate_rids
        self._applied = applied
        self._reject = reject
        self._healthy = healthy
        self._seen_rid = seen_rid
        self.apply_rows = apply_rows
        self.max_lag_bytes = max_lag_bytes
        self._cond = threading.Condition()
        self._pending: deque[_Pending] = deque()
        self.lag_bytes = 0
        self.acked_seq = self.applied_seq = log_.last_seq
        self.applied_batches = 0
        self.applied_samples = 0
        self.failure: str | None = None  # why the applier is retrying, for /health
        self.log_failure: str | None = None  # why the last append to the log failed, until one succeeds
        self.write_failures = 0  # appends the log refused (disk full, not writable)
        self._waiters: list[tuple[int, asyncio.AbstractEventLoop, asyncio.Future]] = []
        self._closing = False
        self._writer = GroupCommitter(lambda: _LogAppender(self._log_group), name="tsdb-log", threads=1)
        self._applier = threading.Thread(target=self._apply_loop, name="tsdb-apply", daemon=True)

    # -- life -----------------------------------------------------------------------------

    def start(self) -> None:
        """Queue what the log holds past the database (a crash's leftovers), then run."""
        self._replay()
        self._writer.start()
        self._applier.start()

    def _replay(self) -> None:
        """Queue every record past the log position the database holds; row
        ids go on above every id the log gave."""
        held = self._applied()
        replayed, highest = 0, held.rid
        for seq, payload in self.log.records(after_seq=held.seq):
            op = codec.decode(payload)
            highest = max([highest, *(e.rid for e in op.entities if e.rid is not None)])
            kept = _unapplied_part(op, held.rid)
            self._queue([_pending(seq, kept, payload)])  # even empty: the position must move past it
            replayed += len(kept.entities)
        self._seen_rid(highest)
        self.acked_seq = self.log.last_seq
        if self._pending:
            self.applied_seq = self._pending[0].seq - 1
            if replayed:
                log.warning("replaying %d notifications from the ingest log %s", replayed, self.log.directory)
        else:
            self.applied_seq = self.log.last_seq
            self.log.reset()  # every record is in the database

    def close(self) -> None:
        """Stop taking writes, apply everything acknowledged, stop."""
        self._writer.close()
        with self._cond:
            self._closing = True
            self._cond.notify_all()
        if self._applier.is_alive():
            self._applier.join()
        self.log.close()

    def observe(self, observer: CommitObserver) -> None:
        """Tell ``observer`` of each acknowledged group (telemetry)."""
        self._writer.observer = observer

    @property
    def alive(self) -> bool:
        return self._writer.alive and self._applier.is_alive()

    # -- writing ----------------------------------------------------------------------------

    async def write(self, op: AppendSamples) -> None:
        """Return once ``op`` is durable in the log."""
        await self._writer.submit(op)

    def write_sync(self, ops: Sequence[AppendSamples]) -> None:
        """Log ``ops`` and return once they are applied (bulk loads, copies)."""
        self._writer.submit_sync(ops)
        self.sync()

    def _log_group(self, ops: Sequence[AppendSamples]) -> None:
        """The log writer's commit: row ids for every entity of the group, in
        order, then one durable record per op; each queued for the applier."""
        self._wait_for_room()
        entities = sum(len(op.entities) for op in ops)
        first = self._allocate_rids(entities)
        for op in ops:
            for entity in op.entities:
                entity.rid = first
                first += 1
        records = [(op, codec.encode(op)) for op in ops]
        try:
            last = self.log.append([payload for _, payload in records])
        except LogError as exc:
            self.write_failures += 1
            self.log_failure = str(exc)
            raise Unavailable(f"{exc}; nothing was stored") from None
        self.log_failure = None
        first = last - len(records) + 1
        self._queue([_pending(first + n, op, payload) for n, (op, payload) in enumerate(records)])

    def _queue(self, items: list[_Pending]) -> None:
        """Hand acknowledged records (in log order) to the applier: one lock
        and one wake-up for a whole group."""
        if not items:
            return
        with self._cond:
            self._pending.extend(items)
            self.lag_bytes += sum(item.nbytes for item in items)
            self.acked_seq = max(self.acked_seq, items[-1].seq)
            self._cond.notify_all()

    def _wait_for_room(self) -> None:
        """The log writer waits while the log runs too far ahead."""
        with self._cond:
            while self.lag_bytes > self.max_lag_bytes and not self._closing:
                self._cond.wait(0.5)

    # -- what /health says of the log ---------------------------------------------------------

    def problem(self) -> str | None:
        """Why the service cannot take notifications or show them (``/health``
        fails): the database refuses the log, or the log cannot be written."""
        if self.failure is not None:
            return self.failure
        if not self.log.writable():
            return f"the ingest log's directory {self.log.directory} is not writable: notifications get 503"
        if self.log_failure is not None:
            return f"{self.log_failure}: notifications get 503 until a write succeeds"
        return None

    def warning(self) -> str | None:
        """What an operator must look at while the service works (``/health``
        warns): records set aside as damaged, until the quarantine folder is
        moved away."""
        if not self.log.quarantined():
            return None
        return (
            f"the ingest log set aside damaged records in {self.log.directory / QUARANTINE}: "
            "inspect them, then move that folder away"
        )

    # -- waiting for the database -------------------------------------------------------------

    async def caught_up(self) -> None:
        """Return once everything acknowledged before this call is applied;
        ``Unavailable`` (503) while the database refuses the log: a read
        could not see what was acknowledged."""
        target = self.acked_seq
        if self.applied_seq >= target:
            return
        loop = asyncio.get_running_loop()
        future = loop.create_future()
        with self._cond:
            if self.applied_seq >= target:
                return
            self._check_failure()
            self._waiters.append((target, loop, future))
        await future

    def sync(self, timeout: float | None = None) -> None:
        """Block until everything acknowledged so far is applied (commands,
        tests, the retention worker: callers that are not on the event loop);
        ``Unavailable`` while the database refuses the log."""
        target = self.acked_seq
        with self._cond:
            done = self._cond.wait_for(
                lambda: self.applied_seq >= target or self._closing or self.failure is not None, timeout
            )
            if self.applied_seq < target:
                self._check_failure()
                if not done:
                    raise Unavailable("the ingest log is not applied yet; retry later")

    def _check_failure(self) -> None:
        if self.failure is not None:
            raise Unavailable(f"the database is catching up with the ingest log ({self.failure}); retry later")

    async def barrier(self) -> None:
        """Before a write that must follow every acknowledged sample."""
        await self.caught_up()

    def _wake(self, error: BaseException | None = None) -> None:
        """Settle the waiting reads: the caught-up ones, or all with ``error``."""
        with self._cond:
            if error is None:
                done = [(loop, f) for seq, loop, f in self._waiters if seq <= self.applied_seq]
                self._waiters = [w for w in self._waiters if w[0] > self.applied_seq]
            else:
                done = [(loop, f) for _, loop, f in self._waiters]
                self._waiters = []
            self._cond.notify_all()
        by_loop: dict[asyncio.AbstractEventLoop, list[asyncio.Future]] = {}
        for loop, future in done:
            by_loop.setdefault(loop, []).append(future)
        for loop, futures in by_loop.items():
            with contextlib.suppress(RuntimeError):  # loop closed: nobody waits
                loop.call_soon_threadsafe(settle, futures, error)

    # -- the applier thread ----------------------------------------------------------------------

    def _apply_loop(self) -> None:
        while True:
            batch = self._take()
            if batch is None or not self._apply_batch(batch):
                return

    def _take(self) -> list[_Pending] | None:
        """The next batch: consecutive records of one ``dedup`` up to
        ``apply_rows`` samples (one op, so one transaction)."""
        with self._cond:
            while not self._pending:
                if self._closing:
                    return None
                self._cond.wait()
            batch: list[_Pending] = []
            rows = 0
            for item in self._pending:
                if batch and (rows + item.samples > self.apply_rows or item.op.dedup != batch[0].op.dedup):
                    break
                batch.append(item)
                rows += item.samples
            return batch

    def _apply_batch(self, batch: list[_Pending]) -> bool:
        """Apply one batch with the log position it completes, retrying until
        it is in; False when the service is closing meanwhile (the log keeps
        the batch for the next start)."""
        op: AppendSamples | None = _merged(batch)
        delay = RETRY_DELAY_S
        attempt = 0
        while op is not None:
            try:
                self._apply([op])
                break
            except Exception as exc:
                attempt += 1
                reason = getattr(exc, "description", None) or str(exc) or type(exc).__name__
                self.failure = f"applying the ingest log to the database failed, retrying: {reason}"
                log.warning("%s (attempt %d)", self.failure, attempt)
                self._wake(Unavailable(f"the database is catching up with the ingest log: {reason}; retry later"))
                if self._closing:
                    return False
                time.sleep(delay)
                delay = min(delay * 2, RETRY_MAX_DELAY_S)
                op = self._unapplied(op)  # a commit whose outcome was unknown may have landed
                if op is not None and attempt >= POISON_ATTEMPTS and self._healthy():
                    op = self._without_poison(op)
        self.failure = None
        self.applied_batches += 1
        self.applied_samples += sum(item.samples for item in batch)
        with self._cond:
            for _ in batch:
                item = self._pending.popleft()
                self.lag_bytes -= item.nbytes
            self.applied_seq = batch[-1].seq
        self.log.drop_upto(self.applied_seq)
        self._wake()
        return True

    def _unapplied(self, op: AppendSamples) -> AppendSamples | None:
        """What of ``op`` the database still lacks; None: all of it is in."""
        try:
            held = self._applied()
        except Exception:
            return op  # the database is away: the same op again, later
        position = op.log_position
        assert position is not None
        if held.seq >= position.seq:
            return None
        return _unapplied_part(op, held.rid)

    def _without_poison(self, op: AppendSamples) -> AppendSamples:
        """Try each entity alone, each moving the position's row id; keep the
        ones the database refuses in the rejected store, so one bad entity
        cannot stop all ingest. What is left: the deliveries and the position
        itself. Only while the database takes other writes: a full disk
        refuses every entity, and must not send them all to the rejected
        store."""
        position = op.log_position
        assert position is not None
        for entity in op.entities:
            alone = LogPosition(self.applied_seq, entity.rid or 0)
            try:
                self._apply([AppendSamples([entity], op.dedup, log_position=alone)])
            except Exception as exc:
                log.error("entity %s (row %s) cannot be applied, kept: %s", entity.entity_id, entity.rid, exc)
                self._reject(entity, str(exc))
        return AppendSamples([], op.dedup, op.deliveries, log_position=position)


class _LogAppender(Appender):
    """The log writer's appender: a group is one log append, durable on commit
    (``LoggedWriter._log_group``)."""

    def __init__(self, log_group: Callable[[Sequence[AppendSamples]], None]):
        self._log_group = log_group
        self._staged: list[AppendSamples] = []

    def stage(self, op: WriteOp) -> None:
        if not isinstance(op, AppendSamples):  # pragma: no cover - the store routes other ops around the log
            raise TypeError(f"only samples go through the ingest log, not {type(op).__name__}")
        self._staged.append(op)

    def commit(self) -> None:
        self._log_group(self._staged)
        self._staged = []

    def rollback(self) -> None:
        self._staged = []


def _pending(seq: int, op: AppendSamples, payload: bytes) -> _Pending:
    return _Pending(seq, op, len(payload), sum(len(e.attrs) for e in op.entities))


def _merged(batch: list[_Pending]) -> AppendSamples:
    """A batch (one ``dedup``) as one op, with the log position it completes."""
    entities = [e for item in batch for e in item.op.entities]
    deliveries = tuple(d for item in batch for d in item.op.deliveries)
    rid = max((e.rid for e in entities if e.rid is not None), default=0)
    return AppendSamples(entities, batch[0].op.dedup, deliveries, LogPosition(batch[-1].seq, rid))


def _unapplied_part(op: AppendSamples, held_rid: int) -> AppendSamples:
    """``op`` without the entities the database holds (row ids up to
    ``held_rid``: those an earlier attempt applied one by one). Its MQTT
    deliveries commit with its last transaction, so they stay (recording one
    twice is harmless: ``ON CONFLICT DO NOTHING``)."""
    entities = [e for e in op.entities if e.rid is None or e.rid > held_rid]
    return AppendSamples(entities, op.dedup, op.deliveries, op.log_position)
