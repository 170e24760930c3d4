"""The write seam: what the ingest paths and write routes hand to storage.

Writes are frozen operations (``write.ops``). A caller awaits
``Writer.write(op)``, which returns once the operation is durable; behind it
one group committer (``write.committer``) stages many operations through a
backend's ``Appender`` (``write.appender``) and commits them together.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Protocol

from tsdb_service.write.ops import WriteOp


class Writer(Protocol):
    """Where writes go. ``write`` is the one method to await on the event
    loop; ``write_sync`` is for callers without a loop (bulk loads, copies,
    commands, tests)."""

    async def write(self, op: WriteOp) -> None:
        """Return once ``op`` is durable; raise (``core.errors``) if it is not."""
        ...

    def write_sync(self, ops: Sequence[WriteOp]) -> None:
        """Commit ``ops`` from a thread that is not the event loop."""
        ...
