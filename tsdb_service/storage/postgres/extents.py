"""Where each series has ever been, kept in PostgreSQL (``geo_extents``).

A geo-query on samples first needs the entities that could ever have been
near the queried area. Without help that is a scan of every stored position
(there is no spatial index on samples). So the writers keep, per series with
geo samples, the bounding box of all of them (its *extent*, migration 0006)
in the same transaction as the samples, and a query looks the candidates up
in that small table (a GiST index on the box) instead.

Extents only grow: an upsert takes the union of the stored box and the
batch's (``LEAST``/``GREATEST``), so concurrent writers and replicas compose
in any order, and a delete leaves them as they are (a box larger than the
remaining positions only costs a few rows read; the exact answer comes from
the samples). The first position of an all-matching series is looked up
when needed (one index probe), so nothing here has to be kept exact.

Each process remembers the extents it has committed (a lower bound of the
stored ones, since those only grow) and sends only boxes that grow them:
robots working within a known area cost no statement at all. Rows are
upserted in series id order, so two writers never wait on each other in
opposite orders.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Sequence

from tsdb_service.core.model import EntitySample
from tsdb_service.storage.postgres.ids import SeriesKey

Box = tuple[float, float, float, float]  # min_lon, min_lat, max_lon, max_lat

UPSERT = (
    "INSERT INTO geo_extents (sid, min_lon, min_lat, max_lon, max_lat) "
    "SELECT s.sid, b.min_lon, b.min_lat, b.max_lon, b.max_lat FROM unnest("
    "%s::text[], %s::text[], %s::text[], %s::text[], %s::text[], "
    "%s::float8[], %s::float8[], %s::float8[], %s::float8[]) "
    "AS b(tenant, service_path, entity_id, entity_type, attr, min_lon, min_lat, max_lon, max_lat) "
    "JOIN series s USING (tenant, service_path, entity_id, entity_type, attr) ORDER BY s.sid "
    "ON CONFLICT (sid) DO UPDATE SET "
    "min_lon = LEAST(geo_extents.min_lon, EXCLUDED.min_lon), min_lat = LEAST(geo_extents.min_lat, EXCLUDED.min_lat), "
    "max_lon = GREATEST(geo_extents.max_lon, EXCLUDED.max_lon), "
    "max_lat = GREATEST(geo_extents.max_lat, EXCLUDED.max_lat) "
    "WHERE EXCLUDED.min_lon < geo_extents.min_lon OR EXCLUDED.min_lat < geo_extents.min_lat "
    "OR EXCLUDED.max_lon > geo_extents.max_lon OR EXCLUDED.max_lat > geo_extents.max_lat"
)


def _nothing() -> None:
    return None


class ExtentLedger:
    """The extents this process knows are stored (per series key)."""

    def __init__(self) -> None:
        self._known: dict[SeriesKey, Box] = {}
        self._lock = threading.Lock()

    def record(self, cur, entities: Sequence[EntitySample]) -> Callable[[], None]:
        """Upsert (with ``cur``, inside the writer's transaction) the extents
        the batch's geo samples grow. Returns what to call once the
        transaction committed: only then are the grown extents stored."""
        grown = self._grown(entities)
        if not grown:
            return _nothing
        keys = list(grown)
        columns = [list(col) for col in zip(*keys, strict=True)]
        columns += [list(col) for col in zip(*grown.values(), strict=True)]
        cur.execute(UPSERT, columns)

        def committed() -> None:
            with self._lock:
                known = self._known
                for key, box in grown.items():
                    old = known.get(key)
                    known[key] = box if old is None else _union(old, box)

        return committed

    def _grown(self, entities: Sequence[EntitySample]) -> dict[SeriesKey, Box]:
        """Per series, the box of the batch's geo samples, where it is not
        already inside the known extent."""
        batch: dict[SeriesKey, Box] = {}
        for e in entities:
            for a in e.attrs:
                g = a.geo
                if g is None:
                    continue
                key = (e.tenant, e.service_path, e.entity_id, e.entity_type, a.name)
                box = (g.min_lon, g.min_lat, g.max_lon, g.max_lat)
                old = batch.get(key)
                batch[key] = box if old is None else _union(old, box)
        if not batch:
            return batch
        with self._lock:
            known = self._known
            return {key: box for key, box in batch.items() if not _inside(box, known.get(key))}


def _union(a: Box, b: Box) -> Box:
    return (min(a[0], b[0]), min(a[1], b[1]), max(a[2], b[2]), max(a[3], b[3]))


def _inside(box: Box, extent: Box | None) -> bool:
    return (
        extent is not None
        and box[0] >= extent[0]
        and box[1] >= extent[1]
        and box[2] <= extent[2]
        and box[3] <= extent[3]
    )
