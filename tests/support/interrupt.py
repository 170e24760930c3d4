"""A real target store that is interrupted mid-run, for the resume tests of
``copy`` and ``import quantumleap``."""

from __future__ import annotations

from typing import Any

from tsdb_service.write.ops import AppendSamples

__all__ = ["Interrupted", "InterruptedTarget"]


class Interrupted(Exception):
    """What the interrupted target raises (like Ctrl-C or a crash)."""


class InterruptedTarget:
    """The real target store, interrupted after ``batches`` sample batches
    were committed: everything else goes straight to the store."""

    def __init__(self, store: Any, batches: int):
        self._store, self._left = store, batches

    def __getattr__(self, name: str) -> Any:
        return getattr(self._store, name)

    def write_sync(self, ops: list) -> None:
        if any(isinstance(op, AppendSamples) for op in ops):
            if self._left == 0:
                raise Interrupted
            self._left -= 1
        self._store.write_sync(ops)
