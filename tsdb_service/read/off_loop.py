"""How a read leaves the event loop: the implementation of ``Store.read``.

DuckDB blocks and PostgreSQL waits on the network, so no database call may
run on the event loop. Yet many reads (``lastN`` from the in-memory tails, a
series lookup in the catalog, a registered ``values`` layout) need no
database, and handing them to the threadpool would cost more than the
answer itself. So a read first runs on the loop with ``MEMORY_ONLY`` set:
every database access calls ``check_database_allowed`` first, which raises
``NeedsDatabase`` before touching the database, and the read is re-run from
the start in the threadpool. A read that always needs the database goes to
the threadpool at once (``memory_first=False``).

A read of a request that shares the process's read budget
(``core.budget.ReadPool``) takes a slot before it goes to the threadpool,
waiting on the loop (not in a thread) while the slots are busy, and gives
it back, with the rows it fetched, when it ends.
"""

from __future__ import annotations

import contextvars
from collections.abc import Callable
from typing import TypeVar

from starlette.concurrency import run_in_threadpool

from tsdb_service.core import budget
from tsdb_service.core.errors import TsdbError

T = TypeVar("T")

MEMORY_ONLY: contextvars.ContextVar[bool] = contextvars.ContextVar("tsdb_memory_only", default=False)


class NeedsDatabase(Exception):
    """Raised instead of a database call while ``MEMORY_ONLY`` is set."""


def check_database_allowed() -> None:
    """Call before any database access a read may make."""
    if MEMORY_ONLY.get():
        raise NeedsDatabase


async def read_off_loop(fn: Callable[[], T], memory_first: bool) -> T:
    """``fn()`` from memory on the loop if it can answer so, else in the
    threadpool. Rows the loop attempt charged to the read budget are given
    back: the re-run reads them again."""
    if memory_first:
        token = MEMORY_ONLY.set(True)
        charged = budget.mark()
        try:
            return fn()
        except NeedsDatabase:
            budget.rewind(charged)
        finally:
            MEMORY_ONLY.reset(token)
    current = budget.pooled()
    try:
        if current is None or current.pool is None:
            return await run_in_threadpool(fn)
        return await _pooled(fn, current, current.pool)
    except TsdbError as exc:
        # An answer (422, 404...), not a bug: its traceback is not needed, and
        # it holds the worker's frames, the rows read included, in a cycle
        # with the thread's future that only a full collection would break
        # (a 100,000-row read refused: 300 ms of garbage collection later).
        raise exc.with_traceback(None) from None


async def _pooled(fn: Callable[[], T], current: budget.ReadBudget, pool: budget.ReadPool) -> T:
    """``fn()`` in the threadpool inside the read pool: entered with a
    small reservation; run again, entered with what it needed (at least
    twice as much), each time it runs out of room."""
    reserve, again = budget.CHUNK_ROWS, False
    charged = budget.mark()
    while True:
        await pool.enter(current, reserve, again)
        try:
            return await run_in_threadpool(fn)
        except budget.OutOfRoom as exc:
            if exc.needed > pool.tenant_rows:
                raise budget.QueryTooLarge(
                    f"this read needs more than the {pool.tenant_rows} rows one tenant may hold at once "
                    f"(TSDB_READ_ROWS_IN_FLIGHT); {budget.NARROW}"
                ) from None
            reserve, again = max(exc.needed, 2 * reserve), True
            budget.rewind(charged)
        finally:
            pool.leave(current)
