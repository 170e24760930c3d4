"""What a PostgreSQL store keeps in memory (``storage.memory``).

Beside the layouts and latest instances both backends keep: the geo extents
and the untimed series this process knows are stored (``extents``,
``untimed``), so a writer sends only what grows them. Other replicas write
too, so nothing here answers a read on its own word where a replica's write
could make it wrong: layouts are read again on a miss or when old
(``PostgresStore.values_layout``), the ledgers are lower bounds of the
database's tables, and the hourly partials live in the querier, checked
against the database's change counts.
"""

from __future__ import annotations

from collections.abc import Callable

from tsdb_service.storage.memory import WriterMemory
from tsdb_service.storage.postgres.extents import ExtentLedger
from tsdb_service.storage.postgres.ids import SeriesKey
from tsdb_service.storage.postgres.untimed import UntimedLedger


class PostgresMemory(WriterMemory):
    """Layouts, latest instances, and the extents and untimed ledgers."""

    def __init__(self, sid_of: Callable[[SeriesKey], int | None]) -> None:
        super().__init__()
        self.extents = ExtentLedger()  # where each series has ever been
        self.untimed = UntimedLedger(sid_of)  # series listed as holding instances without observedAt
