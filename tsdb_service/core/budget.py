"""Read budgets: what one request may cost before it is refused.

A read used to cost whatever it asked for: a SimpleJSON query with 50
wildcard targets over 100k samples took 36 CPU seconds and 1.2 GB to build a
154 MB answer, and ``/v2/attrs`` over 300k series 10.7 s and 951 MB, while
every other client waited (two cores, one GIL). Each request now carries a
budget, checked once per layer:

* **series**: the series one resolution step selects (``SeriesCatalog.select``);
* **rows**: samples and aggregate rows read from storage, summed over the
  request; reads ask for at most the remaining budget plus one row, so an
  overflow is detected without reading further (``history.service``,
  ``storage.sql``);
* **response bytes**: the rendered answer's size (``http.budget``);
* **wall time**: a deadline checked between steps (series resolution, each
  read, each Grafana target).

Running out is ``422 QueryTooLarge`` in the NGSI shape, saying which limit
and how to narrow the query. Limits come from settings (``TSDB_READ_*``).
The budget rides in a context variable set by the middleware, so layers that
are called outside a request (CLI, tests, copies) run without limits, and it
reaches the threadpool because Starlette copies the context into it.

**The budgets of all requests together** (``ReadPool``, one per app). Each
request's budget bounded it alone: 48 aggregations, each refused only after
reading its 500,000 rows, took the process to 6 GB, and 24 heavy Grafana
reads made another tenant's 5-row read take 7 s. So every read that needs
the database first takes a **slot** (``read_concurrency`` reads at once,
one tenant at most half of them) and a reservation of **rows in flight**
(``read_rows_in_flight`` over all reads, one tenant at most half), waiting
on the event loop, not in a thread. The rows it fetches are charged chunk
by chunk as they stream from the database (``fetch_all``), not after: from
its reservation, then from what is free; when nothing is, the read lets go
of everything and waits its turn to run again with the reservation it
needs (``OutOfRoom``), so no read ever waits holding rows another waits
for. A heavy tenant's reads queue behind each other; another tenant's find
a free slot and room at once. A read that waits longer than
``queue_seconds`` in all is refused: ``503 ServerBusy`` with
``Retry-After``.
"""

from __future__ import annotations

import asyncio
import contextvars
import math
import threading
import time
from collections import Counter, deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from tsdb_service.core.errors import TsdbError

NARROW = (
    "narrow the query: fewer entities (id, type, idPattern) or attributes (attrs), a time window "
    "(fromDate/toDate, or from/to on Grafana), fewer rows (lastN, limit), or aggregation "
    "(aggrMethod/aggrPeriod, or Grafana's downsampling)"
)


class QueryTooLarge(TsdbError):
    """The request would cost more than its budget; the client can narrow it."""

    status = 422
    error = "QueryTooLarge"
    ld_type = "TooComplexQuery"  # on /ngsi-ld/ paths


@dataclass(frozen=True, slots=True)
class ReadLimits:
    max_series: int
    max_rows: int
    max_response_bytes: int
    max_seconds: float

    @classmethod
    def from_settings(cls, settings) -> ReadLimits:
        return cls(
            settings.read_max_series,
            settings.read_max_rows,
            settings.read_max_response_bytes,
            settings.read_max_seconds,
        )


class ServerBusy(TsdbError):
    """The reads in flight fill the process's read budget (``ReadPool``) and
    this one waited its time: nothing is wrong with it; retry shortly."""

    status = 503
    error = "ServerBusy"
    ld_type = "InternalError"
    retry_after_s = 1

    @property
    def headers(self) -> dict[str, str]:
        return {"Retry-After": str(self.retry_after_s)}


# Rows a read fetches at a time while they are charged to the pool, and what
# a read reserves when it starts (more, if it needs more, when it runs again).
CHUNK_ROWS = 2_000


class OutOfRoom(Exception):
    """Raised in a reading thread: the read has used its reservation and the
    pool has no more room now. It must not wait holding rows (reads waiting
    on each other would never end): ``read.off_loop`` lets it go, waits on
    the loop for ``needed`` rows, and runs it again from the start."""

    def __init__(self, needed: int):
        super().__init__(needed)
        self.needed = needed


class ReadPool:
    """Every read's slot and rows in flight, in one process: see the module docstring.

    A read **enters** (on the event loop) with a reservation of rows and a
    slot, waiting in its tenant's queue (first come, first served; tenants
    served round-robin) until both are free, and **leaves** giving both back.
    In its thread it **takes rows** as they stream: from its reservation,
    then from what is free, never waiting (``OutOfRoom``). Holding nothing
    while waiting, no two reads can wait on each other. The tenant is the one
    a request names (a fairness key, not an authorisation).
    """

    def __init__(self, slots: int, rows: int, queue_seconds: float, read_rows: int = 0):
        self.slots = max(1, slots)
        self.tenant_slots = max(1, math.ceil(self.slots / 2))
        # A tenant holds at most half the rows, and never less than one
        # whole read may need (its TSDB_READ_MAX_ROWS and the row past it).
        self.tenant_rows = max(1, rows // 2, read_rows + CHUNK_ROWS)
        self.rows = max(rows, self.tenant_rows)
        self.queue_seconds = queue_seconds
        self._lock = threading.Lock()
        self._slots_used = 0
        self._slots_of: Counter[str] = Counter()
        self._rows_used = 0
        self._rows_of: Counter[str] = Counter()
        # tenant → reads waiting to enter, in order: (wake-up, rows to reserve)
        self._waiting: dict[str, deque[tuple[asyncio.Future, int]]] = {}
        self.queued = 0  # reads that waited to enter
        self.refused = 0  # reads answered ServerBusy

    # -- entering and leaving (the event loop) --------------------------------------------

    async def enter(self, budget: ReadBudget, reserve: int, again: bool = False) -> None:
        """Take a slot and ``reserve`` rows for ``budget``'s read: at once
        when free (and its tenant has no read waiting before it), else in
        turn; ``again``: a read that ran out of room goes first in its
        tenant's queue. ``ServerBusy`` past the budget's queue deadline."""
        tenant = budget.tenant
        reserve = min(reserve, self.tenant_rows)
        with self._lock:
            # After every grant no waiting read could enter, so room that is
            # free is this read's unless its own tenant's reads wait before it.
            if tenant not in self._waiting and self._fits(tenant, reserve):
                self._take(tenant, reserve)
                budget.reserved = reserve
                return
            future = asyncio.get_running_loop().create_future()
            queue = self._waiting.setdefault(tenant, deque())
            if again:
                queue.appendleft((future, reserve))
            else:
                queue.append((future, reserve))
            self.queued += 1
        try:
            await asyncio.wait_for(asyncio.shield(future), max(0.0, budget.queue_deadline - time.monotonic()))
        except BaseException as exc:  # timed out, or the request was cancelled (client gone)
            with self._lock:
                granted = future.done() and not future.cancelled()
                if not granted:
                    future.cancel()
                    self._forget(tenant, future)
            if granted:
                budget.reserved = reserve
                if isinstance(exc, TimeoutError):
                    return  # granted as the wait ended: it may run
                self.leave(budget)
            if isinstance(exc, TimeoutError):
                raise self._busy() from None
            raise
        budget.reserved = reserve

    def leave(self, budget: ReadBudget) -> None:
        """Give back the read's slot and rows; let the next reads in."""
        tenant = budget.tenant
        with self._lock:
            self._slots_used -= 1
            self._slots_of[tenant] -= 1
            if not self._slots_of[tenant]:
                del self._slots_of[tenant]
            self._rows_used -= budget.reserved
            self._rows_of[tenant] -= budget.reserved
            if self._rows_of[tenant] <= 0:
                del self._rows_of[tenant]
            budget.reserved = budget.held_rows = 0
            self._grant()

    def _fits(self, tenant: str, reserve: int) -> bool:
        return (
            self._slots_used < self.slots
            and self._slots_of[tenant] < self.tenant_slots
            and self._rows_used + reserve <= self.rows
            and self._rows_of[tenant] + reserve <= self.tenant_rows
        )

    def _take(self, tenant: str, reserve: int) -> None:
        self._slots_used += 1
        self._slots_of[tenant] += 1
        self._rows_used += reserve
        self._rows_of[tenant] += reserve

    def _grant(self) -> None:
        """Let waiting reads in while they fit, one tenant after another,
        each tenant's in order."""
        progress = True
        while progress and self._waiting:
            progress = False
            for tenant in list(self._waiting):
                queue = self._waiting[tenant]
                while queue and queue[0][0].done():  # gave up meanwhile
                    queue.popleft()
                if not queue:
                    del self._waiting[tenant]
                    continue
                future, reserve = queue[0]
                if not self._fits(tenant, reserve):
                    continue
                queue.popleft()
                self._take(tenant, reserve)
                future.set_result(None)
                del self._waiting[tenant]
                if queue:  # to the back of the round
                    self._waiting[tenant] = queue
                progress = True
                break

    def _forget(self, tenant: str, future: asyncio.Future) -> None:
        queue = self._waiting.get(tenant)
        if queue is None:
            return
        for entry in list(queue):
            if entry[0] is future:
                queue.remove(entry)
        if not queue:
            del self._waiting[tenant]

    # -- rows (the reading threads) -------------------------------------------------------

    def take_rows(self, budget: ReadBudget, n: int) -> None:
        """Count ``n`` rows just fetched by ``budget``'s read: from its
        reservation, else from what is free now; ``OutOfRoom`` otherwise."""
        tenant = budget.tenant
        with self._lock:
            needed = budget.held_rows + n
            extra = needed - budget.reserved
            if extra > 0:
                if self._rows_used + extra > self.rows or self._rows_of[tenant] + extra > self.tenant_rows:
                    raise OutOfRoom(needed)
                self._rows_used += extra
                self._rows_of[tenant] += extra
                budget.reserved = needed
            budget.held_rows = needed

    def _busy(self) -> ServerBusy:
        with self._lock:
            self.refused += 1
        return ServerBusy(
            f"the service is busy with other reads: this one waited {self.queue_seconds:g} s "
            "(TSDB_READ_QUEUE_SECONDS) for its turn and was not run; retry in a moment"
        )

    def snapshot(self) -> dict[str, int]:
        """Numbers for ``/metrics``."""
        with self._lock:
            waiting = sum(len(q) for q in self._waiting.values())
            return {
                "slots_used": self._slots_used,
                "rows_used": self._rows_used,
                "waiting": waiting,
                "queued": self.queued,
                "refused": self.refused,
            }


class ReadBudget:
    """One request's allowance; shared by the threads serving that request."""

    __slots__ = ("deadline", "held_rows", "limits", "pool", "queue_deadline", "reserved", "rows", "tenant")

    def __init__(self, limits: ReadLimits, pool: ReadPool | None = None, tenant: str = ""):
        self.limits = limits
        now = time.monotonic()
        self.deadline = now + limits.max_seconds
        self.rows = 0
        self.pool = pool
        self.tenant = tenant
        self.held_rows = 0  # rows the read running now fetched
        self.reserved = 0  # rows the read running now holds in the pool (at least held_rows)
        self.queue_deadline = now + (pool.queue_seconds if pool is not None else 0.0)

    def check_series(self, n: int) -> None:
        if n > self.limits.max_series:
            raise QueryTooLarge(
                f"this query selects {n} series, more than the {self.limits.max_series} one request may read "
                f"(TSDB_READ_MAX_SERIES); {NARROW}"
            )

    def row_cap(self, limit: int) -> int:
        """``limit``, lowered to one row past what is left of the budget."""
        return max(1, min(limit, self.limits.max_rows - self.rows + 1))

    def charge_rows(self, n: int) -> None:
        self.rows += n
        if self.rows > self.limits.max_rows:
            raise QueryTooLarge(
                f"this query reads more than {self.limits.max_rows} samples or aggregate rows "
                f"(TSDB_READ_MAX_ROWS); {NARROW}"
            )

    def check_time(self) -> None:
        if time.monotonic() > self.deadline:
            raise QueryTooLarge(
                f"this query ran longer than {self.limits.max_seconds:g} s (TSDB_READ_MAX_SECONDS) and was "
                f"stopped; {NARROW}"
            )


_CURRENT: contextvars.ContextVar[ReadBudget | None] = contextvars.ContextVar("tsdb_read_budget", default=None)


def current() -> ReadBudget | None:
    return _CURRENT.get()


def check_series(n: int) -> None:
    """Series selected by one resolution step; also a deadline checkpoint."""
    budget = _CURRENT.get()
    if budget is not None:
        budget.check_time()
        budget.check_series(n)


def row_cap(limit: int) -> int:
    budget = _CURRENT.get()
    return limit if budget is None else budget.row_cap(limit)


def charge_rows(n: int) -> None:
    """Rows just read; also a deadline checkpoint."""
    budget = _CURRENT.get()
    if budget is not None:
        budget.charge_rows(n)
        budget.check_time()


def checkpoint() -> None:
    """Between steps: stop a request that is past its deadline."""
    budget = _CURRENT.get()
    if budget is not None:
        budget.check_time()


def mark() -> int | None:
    """Rows charged so far, to ``rewind`` to when a step is redone (a read
    tried from memory first and re-run in the threadpool)."""
    budget = _CURRENT.get()
    return None if budget is None else budget.rows


def rewind(rows: int | None) -> None:
    budget = _CURRENT.get()
    if budget is not None and rows is not None:
        budget.rows = rows


def begin(limits: ReadLimits, pool: ReadPool | None = None, tenant: str = "") -> contextvars.Token:
    """Give the current context (one request) a fresh budget, sharing
    ``pool`` with the other requests; ``end`` with the token."""
    return _CURRENT.set(ReadBudget(limits, pool, tenant))


def pooled() -> ReadBudget | None:
    """The current request's budget when it shares a ``ReadPool``, else None."""
    current = _CURRENT.get()
    return current if current is not None and current.pool is not None else None


def fetch_all(cursor: Any, pooled_read: bool = True) -> list:
    """``cursor.fetchall()``, in chunks charged to the read pool as they
    come (a DB-API cursor: ``fetchmany``); outside a pooled request, or for
    a load that fills a shared cache (``pooled_read=False``), at once."""
    current = pooled() if pooled_read else None
    if current is None:
        return cursor.fetchall()
    pool = current.pool
    assert pool is not None
    out: list = []
    fetch: Callable[[int], list] = cursor.fetchmany
    while rows := fetch(CHUNK_ROWS):
        pool.take_rows(current, len(rows))
        out += rows
        if len(rows) < CHUNK_ROWS:
            break
    return out


def end(token: contextvars.Token) -> None:
    _CURRENT.reset(token)
