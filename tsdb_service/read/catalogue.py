"""The series catalogue: which series exist, by tenant, entity and attribute.

A series is one attribute of one entity (NGSI-LD: one attribute instance
chain, see ``SeriesCatalogue.series``). Every other read takes series ids,
so a read starts here.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Protocol

from tsdb_service.core.query import Scope, SeriesRef
from tsdb_service.read.requests import SeriesSelect


class SeriesCatalogue(Protocol):
    def series(self, ask: SeriesSelect) -> list[SeriesRef]:
        """``SeriesRef``s matching ``ask``, from the in-memory catalog; may
        query the database to catch up with series created since (another
        replica's too).

        NGSI-LD: an attribute instance lives in a series. The default
        instance (no datasetId) in the series named after the attribute,
        each other datasetId in its own series named ``attr~datasetId`` (how
        NGSIv2 sees it), with ``ref.dataset_id`` set and ``ref.ld_attr`` the
        NGSI-LD name. Select by ``ref.ld_attr`` (and ``ref.dataset_id`` for
        a ``datasetId`` filter) rather than with ``attrs``, which matches
        stored names. Names are stored as notified or written (no JSON-LD
        expansion). NGSI-LD has no service paths: use ``Scope(tenant)``."""
        ...

    def series_names(self, scope: Scope) -> dict[str, dict[str, tuple[str, ...]]]:
        """Entity type → {NGSI-LD attribute name (``ref.ld_attr``): the stored
        names of its series} in ``scope``'s tenant, from the catalog. The
        result is shared: do not change it. Lets a query over whole types
        pick the (type, attribute) series it needs instead of listing every
        series of the types."""
        ...

    def tenants(self) -> list[str]:
        """Every tenant with at least one series, sorted (from the catalog)."""
        ...

    def sids_with_samples(self, sids: Sequence[int]) -> set[int]:
        """Those of ``sids`` that hold at least one sample."""
        ...
