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
"""

from __future__ import annotations

import contextvars
from collections.abc import Callable
from typing import TypeVar

from starlette.concurrency import run_in_threadpool

from tsdb_service.core import budget

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
    return await run_in_threadpool(fn)
