"""A ``ServiceStore`` in memory, for tests of routes and for embedders.

Reads go through a ``read.memory.MemoryQuerier``; writes are recorded in
``written`` (not applied), so a route test asserts what a route asked to
store. ``create_app(settings, store=MemoryStore(...))`` serves it.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any, TypeVar

from tsdb_service.core.backup import BackupRefused, BackupReport
from tsdb_service.parse import ValuesLayout
from tsdb_service.read.memory import MemoryQuerier
from tsdb_service.write.ops import WriteOp

T = TypeVar("T")


class MemoryStore:
    """What a route sees of a store (``http.store.ServiceStore``), in memory:
    reads through a ``MemoryQuerier``, writes recorded in ``written``."""

    backend = "memory"

    def __init__(self, querier: MemoryQuerier | None = None):
        self._querier = querier or MemoryQuerier()
        self.written: list[WriteOp] = []
        self.layouts_by_tenant: dict[str, dict[str, ValuesLayout]] = {}

    def querier(self) -> MemoryQuerier:
        return self._querier

    async def read(self, fn: Callable[[], T], *, memory_first: bool = True, consistent: bool = True) -> T:
        return fn()  # memory only: nothing to take off the loop

    async def write(self, op: WriteOp) -> None:
        self.written.append(op)

    def write_sync(self, ops: Sequence[WriteOp]) -> None:
        self.written.extend(ops)

    def values_layout(self, tenant: str, subscription_id: str) -> ValuesLayout | None:
        return self.layouts_by_tenant.get(tenant, {}).get(subscription_id)

    def layouts(self, tenant: str) -> dict[str, ValuesLayout]:
        return dict(self.layouts_by_tenant.get(tenant, {}))

    def rejected_page(
        self, tenant: str | None, limit: int, offset: int, max_bytes: int
    ) -> tuple[list[dict[str, Any]], int | None]:
        return [], None

    def deliveries(self, client_id: str, limit: int) -> list[tuple[int, int, bytes]]:
        return []  # no MQTT message is recorded in memory

    def health(self) -> dict[str, Any]:
        return {"status": "pass", "backend": self.backend}

    def backup(self, path: str) -> BackupReport:
        raise BackupRefused("a store in memory has nothing to back up")

    def close(self) -> None:
        pass
