"""Batches committed in the background, one at a time, in order, while the next is prepared.

An import reads and converts the next batch while the previous one is
written; ``InOrder`` keeps that overlap safe: a batch is submitted only
after the one before it committed (its failure is raised then, in the
caller's thread), so the target always holds a prefix of what was
submitted, and ``close`` waits for the batch in flight (at Ctrl-C too: it
ends committed or not, never half). Used from one thread.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any


class InOrder:
    def __init__(self, write: Callable[[Sequence[Any]], None], name: str):
        self._write = write
        self._pool = ThreadPoolExecutor(1, thread_name_prefix=name)
        self._pending: Future | None = None

    def submit(self, ops: Sequence[Any]) -> None:
        """Write ``ops`` in the background, once the batch before is committed."""
        self.wait()
        self._pending = self._pool.submit(self._write, ops)

    def wait(self) -> None:
        """Until the batch in flight is committed (or its failure raised here)."""
        if self._pending is not None:
            pending, self._pending = self._pending, None
            pending.result()

    def close(self) -> None:
        self._pool.shutdown()
