"""History reads: samples, aggregates and latest values of series.

What the QuantumLeap API, Grafana and the explorer read (``history``).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Protocol

from tsdb_service.core.query import AggregateRow, LastValueRow, LatestRow, RawRow
from tsdb_service.read.requests import AggregateRead, RowsRead, SamplesIn, ValuesAt


class SampleReader(Protocol):
    def raw_rows(self, ask: RowsRead) -> list[RawRow]:
        """Samples of the selected rows (``RowsRead``), oldest first, as
        tuples in the layout ``query.RawRow`` names. DuckDB may answer from
        memory (its tails)."""
        ...

    def aggregate(self, ask: AggregateRead) -> list[AggregateRow]:
        """Per-series (and per period when ``agg.period``) partial aggregates
        of each branch, whole hours and minutes read from rollups where the
        period is made of them (and what rollups keep of samples retention
        deleted; never under a mask or at a value path). The caller combines
        them across series. One statement; a backend may answer from memory
        (its hourly partials)."""
        ...

    def latest_index(self, ask: SamplesIn) -> list[LatestRow]:
        """Each series' newest sample time in ``ask.time`` (series without one: no row)."""
        ...

    def last_values(self, sids: Sequence[int]) -> list[LastValueRow]:
        """Each series' newest sample (by time, then row)."""
        ...

    def values_at(self, ask: ValuesAt) -> list[LastValueRow]:
        """Each series' newest sample at or before ``ask.at`` (by time, then
        row; series without one: no row): the state as of an instant, as
        ``last_values`` is the state now."""
        ...

    def count(self, ask: SamplesIn) -> int:
        """Samples of ``ask.sids`` in ``ask.time``; when there are none (and no
        mask), the rolled-up hours a delete would remove: non-zero whenever a
        delete has something to remove."""
        ...
