"""The backend's half of the write seam: stage operations, commit them as one."""

from __future__ import annotations

from abc import ABC, abstractmethod

from tsdb_service.write.ops import WriteOp


class Appender(ABC):
    """Stages write operations and commits them as one transaction.

    Owned by exactly one writer thread; never shared.
    """

    @abstractmethod
    def stage(self, op: WriteOp) -> None: ...

    @abstractmethod
    def commit(self) -> None:
        """Make everything staged durable, or raise and leave nothing."""

    @abstractmethod
    def rollback(self) -> None: ...

    def refuses(self, exc: BaseException) -> bool:
        """Did ``commit`` fail with ``exc`` because of what was staged (a
        value the database cannot hold, a constraint it breaks), so that the
        same operation would fail again however often it is tried? False
        for the database's own trouble (unreachable, disk full, busy), which
        passes. The group committer sets such an operation aside
        (``NotStorable``) instead of failing every retry with 503."""
        return False

    def close(self) -> None:  # noqa: B027 - optional hook
        pass
