"""Answer from memory on the event loop, or go to the database in a thread.

A history read that the in-memory catalog and tails can answer needs no
database call, and handing it to the threadpool would cost more than the
answer itself. The route first runs it with ``MEMORY_ONLY`` set: any
database access raises ``NeedsDatabase`` before touching the database,
and the route re-runs the read in the threadpool. So no database call ever
runs on the event loop.
"""

from __future__ import annotations

import contextvars
from collections.abc import Callable
from typing import TypeVar

from starlette.concurrency import run_in_threadpool

from .. import budget

T = TypeVar("T")

MEMORY_ONLY: contextvars.ContextVar[bool] = contextvars.ContextVar("tsdb_memory_only", default=False)


class NeedsDatabase(Exception):
    """Raised instead of a database call while ``MEMORY_ONLY`` is set."""


def check_database_allowed() -> None:
    if MEMORY_ONLY.get():
        raise NeedsDatabase


async def in_memory_or_threadpool(fn: Callable[..., T], *args, **kwargs) -> T:
    token = MEMORY_ONLY.set(True)
    charged = budget.mark()
    try:
        return fn(*args, **kwargs)
    except NeedsDatabase:
        budget.rewind(charged)  # the re-run below reads those rows again
    finally:
        MEMORY_ONLY.reset(token)
    return await run_in_threadpool(fn, *args, **kwargs)
