"""The series catalogue over SQL: the catalog in memory, and which series hold samples."""

from __future__ import annotations

from collections.abc import Sequence

from tsdb_service.core.query import Scope, SeriesRef
from tsdb_service.read.catalogue import SeriesCatalogue
from tsdb_service.read.requests import SeriesSelect
from tsdb_service.storage.sql.reads import SqlReads


class SqlSeries(SqlReads, SeriesCatalogue):
    def series(self, ask: SeriesSelect) -> list[SeriesRef]:
        return self.catalog.select(ask.scope, ask.entities, ask.attrs)

    def series_names(self, scope: Scope) -> dict[str, dict[str, tuple[str, ...]]]:
        return self.catalog.names(scope.tenant)

    def tenants(self) -> list[str]:
        return self.catalog.tenants()

    def sids_with_samples(self, sids: Sequence[int]) -> set[int]:
        if not sids:
            return set()
        where, params = self.dialect.sid_filter(sids)
        sql = f"SELECT DISTINCT sid FROM {self.dialect.samples('sid')} WHERE {where}"
        return {row[0] for row in self._fetch(sql, params)}
