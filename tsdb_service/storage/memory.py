"""What a store keeps in memory of what its writers committed.

Invariant: **never ahead of the database.** A writer publishes here only
after the commit that made a thing true (``publish_*``), and a store forgets
what a delete, an instance edit or a retention batch changed (``forget``):
the next read loads it again from the database. Each piece keeps its own
lock (``docs/architecture.md``, *Caches and locks*); this owner only groups
them, so the writer, the store and retention reach them the same way.

What both backends keep: the ``values`` layouts (``storage.layouts``) and
each series' latest NGSI-LD instance (``storage.ld_ingest``). A backend's
memory adds its own (DuckDB: tails, hourly partials, latest locations;
PostgreSQL: the extents and untimed-series ledgers).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

from tsdb_service.storage.layouts import Layouts
from tsdb_service.storage.ld_ingest import InstanceKey, LatestInstances, publish_staged
from tsdb_service.write.ops import PutLayout


class WriterMemory:
    """The layouts and latest instances a store answers from memory."""

    def __init__(self) -> None:
        self.layouts = Layouts()
        self.latest_instances = LatestInstances()

    def publish_layouts(self, puts: Sequence[PutLayout]) -> None:
        """After the commit that stored ``puts``."""
        self.layouts.publish(puts)

    def publish_instances(self, staged: dict[tuple, InstanceKey], sid_of: Callable[[tuple], int | None]) -> None:
        """After a commit: the latest instances a writer staged (by series
        key, ``ld_ingest.drop_renotified``) are the stored ones now."""
        publish_staged(self.latest_instances, staged, sid_of)

    def forget(self, sids: Sequence[int]) -> None:
        """Series whose stored samples were deleted or changed: let go of
        them; they load again from the database when next asked."""
        self.latest_instances.drop(sids)
