"""Location reads over SQL: latest positions, first positions, geo samples."""

from __future__ import annotations

from abc import abstractmethod
from collections.abc import Callable, Sequence
from datetime import datetime

from tsdb_service.core.query import (
    EntityFilter,
    ExtentRow,
    FirstLocationRow,
    GeometryRow,
    LocationRow,
    SeriesRef,
    TimeRange,
)
from tsdb_service.read.locations import LocationReader
from tsdb_service.read.requests import ExtentsNear, LocatedSelect, LocationsIn, SeriesSelect
from tsdb_service.storage.sql.dialect import GEO_KIND, box_test, latest_per_series, rows_as
from tsdb_service.storage.sql.reads import SqlReads

LOCATION_COLUMNS = "sid, rid, t, kind, geo, min_lon, min_lat, max_lon, max_lat"
as_geometries = rows_as(GeometryRow)
as_first_locations = rows_as(FirstLocationRow)


class SqlLocations(SqlReads, LocationReader):
    series: Callable[[SeriesSelect], list[SeriesRef]]  # the catalogue's (``storage.sql.series``)

    def latest_geometries(self, ask: LocationsIn) -> list[GeometryRow]:
        """See ``LocationReader``: the latest first, then the box test."""
        if not ask.sids:
            return []
        d = self.dialect
        where, params = self._where(ask.sids, ask.time)
        test, test_params = box_test(d, ask.prefilter)
        source = d.samples("sid, rid, t, kind, geo, min_lon, min_lat, max_lon, max_lat")
        latest = latest_per_series(
            "sid, geo, min_lon, min_lat, max_lon, max_lat", source, f"{where} AND kind = {GEO_KIND}"
        )
        sql = f"SELECT sid, geo FROM ({latest}) latest WHERE {test}"
        return as_geometries(self._fetch(sql, [*params, *test_params]))

    def located_series(self, ask: LocatedSelect) -> list[SeriesRef]:
        """The extents (memory on DuckDB; a GiST search by box on
        PostgreSQL) give the few series near the box, each looked up in the
        catalog's (types, attrs) set, which it keeps between requests: no
        list of the types' 100,000 series per request."""
        if not ask.scope.whole_tenant:
            refs = self.series(SeriesSelect(ask.scope, EntityFilter(types=tuple(ask.types)), ask.attrs))
            near = {row[0] for row in self.location_extents(ExtentsNear([r.sid for r in refs], ask.prefilter))}
            return [r for r in refs if r.sid in near]
        by_sid = self.catalog.by_sid(ask.scope.tenant, ask.types, ask.attrs)
        return [by_sid[row[0]] for row in self.location_extents(ExtentsNear(by_sid, ask.prefilter))]

    @abstractmethod
    def location_extents(self, ask: ExtentsNear) -> list[ExtentRow]:
        """Kept by each backend (in memory on DuckDB, a table on PostgreSQL):
        from the samples it would cost a scan of every stored position."""

    def first_locations(self, sids: Sequence[int]) -> list[FirstLocationRow]:
        if not sids:
            return []
        d = self.dialect
        where, params = d.sid_filter(sids)
        located = f"{where} AND kind = {GEO_KIND} AND geo IS NOT NULL"
        source = d.samples("sid, rid, t, kind, geo")
        sql = latest_per_series(f"sid, {d.epoch_us('t')}, rid", source, located, inner="sid, t, rid", order="t, rid")
        return as_first_locations(self._fetch(sql, params))

    def location_samples(self, ask: LocationsIn) -> list[LocationRow]:
        """See ``LocationReader``."""
        if not ask.sids:
            return []
        d = self.dialect
        parts, params = self._location_rows(ask.sids, ask.time)
        test, test_params = box_test(d, ask.prefilter)
        sql = (
            "SELECT sid, t_us, rid, ok, pt, min_lon, min_lat, CASE WHEN ok AND NOT pt THEN geo END FROM ("
            f"SELECT sid, {d.epoch_us('t')} AS t_us, rid, geo, min_lon, min_lat, {test} AS ok, "
            f"(min_lon = max_lon AND min_lat = max_lat) AS pt FROM ({parts}) u) x ORDER BY sid, t_us, rid"
        )
        return self._fetch(sql, [*test_params, *params])

    def _location_rows(self, sids: Sequence[int], time: TimeRange) -> tuple[str, list]:
        """SQL and parameters: the rows ``location_samples`` reads."""
        d = self.dialect
        where, params = self._where(sids, time)
        parts = (
            f"SELECT {LOCATION_COLUMNS} FROM {d.samples(LOCATION_COLUMNS)} "
            f"WHERE {where} AND kind = {GEO_KIND} AND geo IS NOT NULL"
        )
        if time.start is not None:
            seeds, seed_params = self._location_seeds(sids, time.start)
            parts = f"{parts} UNION ALL {seeds}"
            params += seed_params
        return parts, params

    def _location_seeds(self, sids: Sequence[int], before: datetime) -> tuple[str, list]:
        """SQL (columns as in ``location_samples``): each series' latest geo
        sample strictly before ``before``."""
        d = self.dialect
        columns = LOCATION_COLUMNS
        where, params = d.sid_filter(sids)
        params.append(d.time_value(before))
        located = f"{where} AND t < {d.placeholder} AND kind = {GEO_KIND} AND geo IS NOT NULL"
        return latest_per_series(columns, d.samples(columns), located), params
