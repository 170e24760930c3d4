"""The base every SQL reader of this package builds on: one connection
method (``_fetch``), the dialect, the series catalog and the shared WHERE."""

from __future__ import annotations

from abc import abstractmethod
from collections.abc import Iterator, Sequence
from typing import Any

from tsdb_service.core.query import RowMask, TimeRange
from tsdb_service.storage.catalog import SeriesCatalog
from tsdb_service.storage.rollups import presence_of
from tsdb_service.storage.sql.dialect import SqlDialect, mask_filter, series_time_filter


class SqlReads:
    """What a backend's querier provides to the readers: run a statement on
    the calling thread's connection (``_fetch``) or on a cursor of its own
    (``_batches``)."""

    dialect: SqlDialect
    catalog: SeriesCatalog
    _store: Any  # the backend's store: its expiry presence tracker (``storage.rollups``)

    @abstractmethod
    def _fetch(self, sql: str, params: list) -> list[tuple]:
        """Run one read on the calling thread's connection; all its rows."""

    @abstractmethod
    def _batches(self, sql: str, params: list, size: int) -> Iterator[list[tuple]]:
        """Run one read on a cursor of its own; its rows ``size`` at a time."""

    def _where(self, sids: Sequence[int], time: TimeRange, mask: RowMask | None = None) -> tuple[str, list]:
        where, params = series_time_filter(self.dialect, sids, time)
        if mask is not None:
            test, more = mask_filter(self.dialect, mask)
            where += f" AND {test}"
            params += more
        return where, params

    def _samples(self, columns: str, mask: RowMask | None) -> str:
        """The FROM item; a mask also needs each sample's row id."""
        if mask is not None and "rid" not in columns.split(", "):
            columns += ", rid"
        return self.dialect.samples(columns)

    def raw_expired(self) -> bool:
        """Retention may have deleted raw samples (``storage.rollups``): the
        hourly partials know raw samples only, so aggregations then go to
        SQL, which reads the rollups."""
        return presence_of(self._store)(self._fetch)
