"""What the DuckDB store keeps in memory of its file (``storage.memory``).

Beside the layouts and latest instances both backends keep: the tails of
recently read series (``tail_cache``), the hourly aggregate partials
(``storage.partials``) and every located series' latest location and extent
(``latest_geo``). The readers (``querier``) answer from them; the one
writer keeps them true:

* ``publish_samples`` after each commit of samples;
* ``forget`` and ``relocate`` after a delete, an instance edit or a
  retention batch, for the series it touched;
* ``fresh`` when the file is (re)opened: locations and layouts as the file
  holds them, the rest empty (they load on demand).

A reopen replaces the pieces (``fresh``), so readers look them up here at
each use and keep no reference across calls.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

from tsdb_service.parse import ValuesLayout
from tsdb_service.storage.duckdb.latest_geo import LatestGeo
from tsdb_service.storage.duckdb.tail_cache import TailCache
from tsdb_service.storage.layouts import LayoutKey
from tsdb_service.storage.ld_ingest import LatestInstances
from tsdb_service.storage.memory import WriterMemory
from tsdb_service.storage.partials import HourlyPartials


class DuckDBMemory(WriterMemory):
    """Tails, partials, latest locations, instances and layouts of one file."""

    def __init__(self, tail_series: int, tail_rows: int, tail_samples: int | None, partials_hours: int):
        super().__init__()
        self._tail_args = (tail_series, tail_rows, tail_samples)
        self._partials_hours = partials_hours
        self.tail = TailCache(*self._tail_args)
        self.partials = HourlyPartials(partials_hours)
        self.latest_geo = LatestGeo(())

    def fresh(self, latest_geo: LatestGeo, layouts: dict[LayoutKey, ValuesLayout]) -> None:
        """The file was (re)opened, with nobody reading or writing: its
        locations and layouts; no tail, partial or latest instance yet."""
        self.tail = TailCache(*self._tail_args)
        self.partials = HourlyPartials(self._partials_hours)
        self.latest_instances = LatestInstances()
        self.latest_geo = latest_geo
        self.layouts.replace(layouts)

    def publish_samples(self, cols: dict[str, list]) -> None:
        """After the commit of a batch (the appender's columns)."""
        self.tail.publish(cols)
        self.latest_geo.publish(cols)
        self.partials.publish(cols)

    def forget(self, sids: Sequence[int]) -> None:
        """Tails, hourly partials and latest instances let go of ``sids``;
        their latest locations are ``relocate``d by the callers, which know
        the rows."""
        self.tail.drop(sids)
        self.partials.drop(sids)
        super().forget(sids)

    def relocate(self, sids: Sequence[int], upto_rid: int, load: Callable[[list[int]], list[tuple]]) -> None:
        """After rows up to ``upto_rid`` of ``sids`` were deleted or changed:
        their latest locations from the file (``load``; extents stay)."""
        self.latest_geo.recompute(sids, upto_rid, load)
