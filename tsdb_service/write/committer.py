"""Group commit: one writer thread, many waiting requests.

Each request queues its write and awaits a future. The writer takes
everything queued, stages it in one transaction, commits once, then wakes all
the waiters together. Throughput comes from amortising the commit; safety
comes from answering only after the commit returned.

If a group fails, its operations are retried one by one, so one poisonous
notification fails alone instead of taking its neighbours down with it. An
appender that knows retrying cannot help (the database is down, or the
commit's outcome is unknown) raises ``Unavailable`` instead: the group is
answered with that error as it stands, never retried, because a retry after a
commit that did land would store everything twice.

**Poison.** A lone operation that fails ``SINGLE_OP_ATTEMPTS`` times, with
an error its appender says is the content's (``Appender.refuses``: a value
the database cannot hold, a constraint it breaks), or while the operations
of its group committed one by one beside it, will never be stored:
its caller gets ``NotStorable`` (4xx), not a 503 inviting a retry that
cannot succeed, and keeps the notification in the rejected store (HTTP
answers 422; MQTT acknowledges it). ``poisoned`` counts them for
``/metrics`` and ``/health``. Any other failure is still ``Unavailable``.

Several writer threads may share the queue. A commit is mostly waiting (for
the log's fsync, for the GIL held by the event loop), so while one writer
waits another can build and send the next group: throughput scales with
writers until the disk or a core is busy.

An optional ``observer`` (``telemetry.WriterMetrics``) hears about each group
as it is taken and settled, from the writer thread: once per group, so
counting costs the request path nothing.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import queue
import threading
import time
from collections.abc import Callable, Sequence
from concurrent.futures import Future as SyncFuture
from typing import Protocol

from tsdb_service.core.errors import NotStorable, Unavailable, first_line
from tsdb_service.write.appender import Appender
from tsdb_service.write.ops import AppendSamples, WriteOp

log = logging.getLogger(__name__)

_STOP = object()
# Cap one group so a burst cannot make one transaction (and its waiters'
# latency) unbounded.
MAX_GROUP = 4096
# A failed single op is tried this many times before its request gets 503.
SINGLE_OP_ATTEMPTS = 3


class CommitObserver(Protocol):
    """Told, from a writer thread, what each group did (all ops of one call share a kind,
    except in ``taken``)."""

    def taken(self, ops: Sequence[WriteOp]) -> None: ...

    def committed(self, ops: Sequence[WriteOp], seconds: float) -> None: ...

    def failed_ops(self, ops: Sequence[WriteOp]) -> None: ...


class _Waiter:
    __slots__ = ("future", "loop", "op")

    def __init__(self, op: WriteOp, loop: asyncio.AbstractEventLoop | None, future):
        self.op = op
        self.loop = loop
        self.future = future


class GroupCommitter:
    def __init__(self, appender_factory: Callable[[], Appender], name: str = "tsdb-writer", threads: int = 1):
        self._queue: queue.SimpleQueue = queue.SimpleQueue()
        self._appender_factory = appender_factory
        self._closed = False
        self._failure: BaseException | None = None
        self.commits = 0
        self.ops = 0
        self.observer: CommitObserver | None = None
        self.poisoned = 0  # operations set aside as NotStorable
        self.last_poison: tuple[float, str] | None = None  # (time.time(), the database's reason)
        self._threads = [threading.Thread(target=self._run, name=f"{name}-{i}", daemon=True) for i in range(threads)]
        self._started = threading.Semaphore(0)
        self._count_lock = threading.Lock()

    def start(self) -> None:
        for thread in self._threads:
            thread.start()
        for _ in self._threads:
            self._started.acquire()
        if self._failure is not None:
            self.close()
            raise self._failure

    @property
    def queue_depth(self) -> int:
        """Ops queued and not yet taken by a writer (approximate, as any queue size)."""
        return self._queue.qsize()

    @property
    def alive(self) -> bool:
        return not self._closed and all(t.is_alive() for t in self._threads)

    async def submit(self, op: WriteOp) -> None:
        if self._closed:
            raise Unavailable("the store is shutting down; retry")
        loop = asyncio.get_running_loop()
        future = loop.create_future()
        self._queue.put(_Waiter(op, loop, future))
        await future

    def submit_sync(self, ops: Sequence[WriteOp]) -> None:
        if self._closed:
            raise Unavailable("the store is shutting down; retry")
        futures = []
        for op in ops:
            future: SyncFuture = SyncFuture()
            self._queue.put(_Waiter(op, None, future))
            futures.append(future)
        for future in futures:
            future.result()

    def close(self) -> None:
        """Stop accepting, commit everything already queued, then stop."""
        if self._closed:
            return
        self._closed = True
        self._queue.put(_STOP)
        for thread in self._threads:
            if thread.is_alive():
                thread.join()

    # -- the writer thread -------------------------------------------------

    def _run(self) -> None:
        try:
            appender = self._appender_factory()
        except BaseException as exc:  # surfaced by start()
            self._failure = exc
            self._started.release()
            return
        self._started.release()
        try:
            while True:
                first = self._queue.get()
                stop = first is _STOP
                group = [] if stop else [first]
                while not stop and len(group) < MAX_GROUP:
                    try:
                        item = self._queue.get_nowait()
                    except queue.Empty:
                        break
                    if item is _STOP:
                        stop = True
                        break
                    group.append(item)
                if group:
                    self._tell("taken", group)
                    self._commit_mixed(appender, group)
                if stop:
                    # Everything queued before close() precedes the stop
                    # marker; pass the marker on so every writer sees it.
                    self._queue.put(_STOP)
                    break
        finally:
            appender.close()

    def _commit_mixed(self, appender: Appender, group: list[_Waiter]) -> None:
        """Samples commit together; the rare other ops (rejections, layouts,
        deletes) one at a time, so a transaction never mixes kinds and a
        retry can never repeat a write that already landed."""
        samples = [w for w in group if isinstance(w.op, AppendSamples)]
        if samples:
            self._commit_group(appender, samples)
        for waiter in group:
            if not isinstance(waiter.op, AppendSamples):
                self._commit_group(appender, [waiter])

    def _commit_group(self, appender: Appender, group: list[_Waiter]) -> None:
        """Commit ``group`` in one transaction; if it fails, each op alone
        (the ones that fail again retried, then set aside or refused)."""
        exc = self._try(appender, group)
        if exc is None:
            return
        if isinstance(exc, Unavailable):
            self._unavailable(group, exc)
            return
        if len(group) == 1:
            self._retry_alone(appender, group[0], exc, others_committed=False)
            return
        log.warning("group commit of %d ops failed; retrying one by one", len(group))
        failures = [(waiter, failure) for waiter in group if (failure := self._try(appender, [waiter])) is not None]
        others_committed = len(failures) < len(group)
        for waiter, failure in failures:
            if isinstance(failure, Unavailable):
                self._unavailable([waiter], failure)
            else:
                self._retry_alone(appender, waiter, failure, others_committed)

    def _retry_alone(self, appender: Appender, waiter: _Waiter, exc: Exception, others_committed: bool) -> None:
        """A lone op that failed once: tried again (a transient conflict with
        another writer passes); failing every time, it is poison when the
        appender says the content is at fault, or when the ops committed
        beside it show the database takes writes; else 503."""
        for attempt in range(1, SINGLE_OP_ATTEMPTS):
            time.sleep(0.005 * attempt)
            failure = self._try(appender, [waiter])
            if failure is None:
                return
            if isinstance(failure, Unavailable):
                self._unavailable([waiter], failure)
                return
            exc = failure
        if others_committed or appender.refuses(exc):
            self._poisoned([waiter], exc)
            return
        log.error("write failed", exc_info=exc)
        self._tell("failed_ops", [waiter])
        _resolve([waiter], Unavailable("the write could not be committed; nothing was stored"))

    def _try(self, appender: Appender, group: list[_Waiter]) -> Exception | None:
        """Stage and commit ``group`` once: None once it is committed (and
        its waiters answered), else the failure (rolled back, unanswered)."""
        start = time.perf_counter()
        try:
            for waiter in group:
                appender.stage(waiter.op)
            appender.commit()
        except Exception as exc:
            appender.rollback()
            return exc
        with self._count_lock:
            self.commits += 1
            self.ops += len(group)
        self._tell("committed", group, time.perf_counter() - start)
        _resolve(group, None)
        return None

    def _unavailable(self, group: list[_Waiter], exc: Unavailable) -> None:
        """The appender says what happened (nothing stored, or unknown): never retried."""
        log.debug("write of %d ops refused: %s", len(group), exc.description)
        self._tell("failed_ops", group)
        _resolve(group, exc)

    def _poisoned(self, group: list[_Waiter], exc: Exception) -> None:
        """The database refused this lone op for its content, every time:
        its caller sets it aside (rejected store) and the rest goes on."""
        reason = first_line(exc)
        kind = type(group[0].op).__name__
        log.error("the database refused a write (%s) %d times for its content: %s", kind, SINGLE_OP_ATTEMPTS, reason)
        with self._count_lock:
            self.poisoned += 1
            self.last_poison = (time.time(), reason)
        _resolve(
            group,
            NotStorable(
                f"the database refused to store this ({reason}); it is not retried and nothing of it was stored"
            ),
        )

    def _tell(self, event: str, group: list[_Waiter], *args) -> None:
        """Report to the observer; its failure must never stop a writer."""
        observer = self.observer
        if observer is None:
            return
        try:
            getattr(observer, event)([w.op for w in group], *args)
        except Exception:
            log.exception("commit observer failed on %s", event)


def _resolve(group: list[_Waiter], error: BaseException | None) -> None:
    """Wake waiters: one thread-safe callback per event loop, not per request."""
    by_loop: dict[asyncio.AbstractEventLoop, list] = {}
    for waiter in group:
        if waiter.loop is None:
            if error is None:
                waiter.future.set_result(None)
            else:
                waiter.future.set_exception(error)
        else:
            by_loop.setdefault(waiter.loop, []).append(waiter.future)
    for loop, futures in by_loop.items():
        with contextlib.suppress(RuntimeError):  # loop already closed: nobody is waiting any more
            loop.call_soon_threadsafe(settle, futures, error)


def settle(futures: list[asyncio.Future], error: BaseException | None) -> None:
    """Settle waiting futures on their loop: the result, or ``error``."""
    for future in futures:
        if future.done():
            continue
        if error is None:
            future.set_result(None)
        else:
            future.set_exception(error)
