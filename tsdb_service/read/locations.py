"""Where series have been: latest positions, extents and geo samples.

What the geo-queries of both APIs read (``history.geo_matching``, ``history.geo_masks``,
the NGSI-LD geo-query). Points come as (lon, lat); other shapes as GeoJSON.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Protocol

from tsdb_service.core.query import ExtentRow, FirstLocationRow, GeometryRow, LocationRow, SeriesRef
from tsdb_service.read.requests import ExtentsNear, LocatedSelect, LocationsIn


class LocationReader(Protocol):
    def latest_geometries(self, ask: LocationsIn) -> list[GeometryRow]:
        """Each series' latest geo sample in ``ask.time`` whose box passes the
        prefilter. The latest is chosen first and filtered after, so an older
        position never stands in. DuckDB answers from memory when the time is
        open."""
        ...

    def location_extents(self, ask: ExtentsNear) -> list[ExtentRow]:
        """Per located series whose extent (the box of every geo sample it
        ever had) may pass the prefilter: the extent and, where the backend
        keeps it, its first position (else None: ``first_locations``).
        Memory only on DuckDB; a table (one query) on PostgreSQL. After a
        delete an extent may be larger than the remaining samples."""
        ...

    def located_series(self, ask: LocatedSelect) -> list[SeriesRef]:
        """The series a type-wide geo-query looks at: those of ``ask.types``
        with a stored name in ``ask.attrs`` whose extent may pass the
        prefilter, as ``location_extents`` decides."""
        ...

    def first_locations(self, sids: Sequence[int]) -> list[FirstLocationRow]:
        """Each series' first geo sample by (time, row)."""
        ...

    def location_samples(self, ask: LocationsIn) -> list[LocationRow]:
        """Every geo sample of ``ask.sids`` in ``ask.time``, plus each series'
        latest one before ``ask.time.start`` (the location its first samples
        in the window had), ordered by (sid, t, rid). Other shapes than
        points only where the box passes the prefilter (the others cannot
        match, so they are not parsed)."""
        ...
