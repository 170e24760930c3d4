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

    def close(self) -> None:  # noqa: B027 - optional hook
        pass
