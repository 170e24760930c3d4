"""The storage seam's guarantees, on both backends: named rows, ``compact``,
copies through seam methods, and an import graph without cycles.

The read seam (``read.Querier``) returns the NamedTuples of
``tsdb_service.core.query``: still tuples (callers unpack them), with names.
Every ``Store`` has ``compact`` (DuckDB sorts, PostgreSQL has nothing to
do). The backend packages depend on the shared storage code, never the
other way round, and never on each other.
"""

from __future__ import annotations

from datetime import UTC, datetime, timedelta
from pathlib import Path

import pytest

from tests.support.imports import module_imports
from tsdb_service.commands.copy import copy_history
from tsdb_service.core.config import Settings
from tsdb_service.core.model import AttrSample, EntitySample, Geometry, Kind
from tsdb_service.core.query import (
    AggBranch,
    AggregateRow,
    Aggregation,
    AggrMethod,
    AggrPeriod,
    EntityFilter,
    ExtentRow,
    FirstLocationRow,
    GeometryRow,
    InstanceRow,
    LastValueRow,
    LatestRow,
    LocationRow,
    RawRow,
    Scope,
    StoredSample,
    TimeRange,
)
from tsdb_service.read import Querier
from tsdb_service.read.requests import (
    AggregateRead,
    ExtentsNear,
    InstancesRead,
    LocationsIn,
    RowsRead,
    SamplesIn,
    SeriesSelect,
)
from tsdb_service.storage import open_store
from tsdb_service.storage.store import Store
from tsdb_service.write.ops import AppendSamples

T0 = datetime(2024, 5, 1, tzinfo=UTC)
SCOPE = Scope("acme")
STORAGE = Path(__file__).resolve().parent.parent / "tsdb_service" / "storage"
BACKENDS = ("duckdb", "postgres")


class _Box:
    min_lon, min_lat, max_lon, max_lat = -10.0, -10.0, 10.0, 10.0


def _point(lon: float, lat: float) -> Geometry:
    return Geometry(f'{{"type":"Point","coordinates":[{lon},{lat}]}}', lon, lat, lon, lat, lon, lat)


def _entities(n: int = 5) -> list[EntitySample]:
    return [
        EntitySample(
            "acme",
            "/",
            "Robot:1",
            "Robot",
            T0 + timedelta(minutes=i),
            [
                AttrSample("speed", "Number", Kind.NUMBER, num=float(i)),
                AttrSample("location", "geo:json", Kind.GEO, js="{}", geo=_point(float(i), 1.0)),
            ],
        )
        for i in range(n)
    ]


@pytest.fixture
def store(store_url):
    s = open_store(Settings(db=store_url))
    s.write_sync([AppendSamples(_entities())])
    yield s
    s.close()


def _sids(q: Querier, attr: str) -> list[int]:
    return [r.sid for r in q.series(SeriesSelect(SCOPE, EntityFilter(ids=("Robot:1",)), {attr}))]


def test_sample_reads_return_named_rows(store):
    q = store.querier()
    speed = _sids(q, "speed")
    # The bulk read: plain tuples in the RawRow layout (from memory and from SQL).
    rows = q.raw_rows(RowsRead(speed, TimeRange(), newest_first=True, limit=3, offset=0, one_per_row=True))
    assert [type(r) for r in rows] == [tuple] * 3
    assert [r[4] for r in rows] == [2.0, 3.0, 4.0]
    sid, _, iso, kind, num, _, _ = rows[-1]
    assert (sid, iso, kind, num) == (speed[0], "2024-05-01T00:04:00.000+00:00", int(Kind.NUMBER), 4.0)
    sql_rows = q.raw_rows(RowsRead(speed, TimeRange(), newest_first=False, limit=2, offset=1, one_per_row=False))
    assert [len(r) for r in sql_rows] == [len(RawRow.__args__)] * 2
    agg = q.aggregate(
        AggregateRead([AggBranch(tuple(speed))], TimeRange(), Aggregation(AggrMethod.SUM, AggrPeriod.HOUR))
    )
    assert [type(r) for r in agg] == [AggregateRow]
    assert (agg[0].n_present, agg[0].value, agg[0].bucket) == (5, 10.0, "2024-05-01T00:00:00.000+00:00")
    latest = q.latest_index(SamplesIn(speed, TimeRange()))
    assert latest == [LatestRow(speed[0], "2024-05-01T00:04:00.000+00:00")]
    assert type(latest[0]) is LatestRow
    last = q.last_values(speed)
    assert type(last[0]) is LastValueRow and last[0].num == 4.0 and last[0].atype == "Number"
    instances = q.temporal_instances(InstancesRead(speed))
    assert {type(r) for r in instances} == {InstanceRow} and len(instances) == 5


def test_location_reads_return_named_rows(store):
    q = store.querier()
    loc = _sids(q, "location")
    prefilter = ("intersects", _Box())
    for time in (TimeRange(), TimeRange(None, T0 + timedelta(hours=1))):  # memory and SQL on DuckDB
        geos = q.latest_geometries(LocationsIn(loc, time, prefilter))
        assert [type(r) for r in geos] == [GeometryRow]
        assert geos[0].sid == loc[0] and '"coordinates":[4.0,1.0]' in geos[0].geojson
    extents = q.location_extents(ExtentsNear(loc, prefilter))
    assert [type(r) for r in extents] == [ExtentRow]
    assert extents[0][:5] == (loc[0], 0.0, 1.0, 4.0, 1.0)
    first = q.first_locations(loc)
    assert [type(r) for r in first] == [FirstLocationRow] and first[0].sid == loc[0]
    samples = q.location_samples(LocationsIn(loc, TimeRange(T0 + timedelta(minutes=2)), prefilter))
    assert {len(r) for r in samples} == {len(LocationRow.__args__)}  # the bulk read: plain tuples
    assert [(r[5], r[3], r[4]) for r in samples] == [(float(i), True, True) for i in range(1, 5)]


def test_compact_is_on_every_store(store):
    assert isinstance(store, Store)
    done = store.compact(full=True)
    assert isinstance(done, str) and done
    q = store.querier()
    rows = q.raw_rows(
        RowsRead(_sids(q, "speed"), TimeRange(), newest_first=False, limit=10, offset=0, one_per_row=True)
    )
    assert [r[4] for r in rows] == [0.0, 1.0, 2.0, 3.0, 4.0]


def test_stored_samples_stream_in_batches(store):
    batches = list(store.querier().stored_samples(3))
    assert [len(b) for b in batches] == [3, 3, 3, 1]
    rows = [r for b in batches for r in b]
    assert {type(r) for r in rows} == {StoredSample}
    assert [r.rid for r in rows] == sorted(r.rid for r in rows)
    assert store.querier().sample_counts() == {"acme": 10}


def test_copy_goes_through_the_seam(store, store_url_factory):
    with_target = open_store(Settings(db=store_url_factory("seam_copy_target")))
    try:
        report = copy_history(store, with_target, source_id="seam-test")
        assert report.target_total == 10
        assert with_target.copy_runs_open() == []
        q = with_target.querier()
        rows = q.raw_rows(
            RowsRead(_sids(q, "speed"), TimeRange(), newest_first=False, limit=10, offset=0, one_per_row=True)
        )
        assert [r[4] for r in rows] == [0.0, 1.0, 2.0, 3.0, 4.0]
        assert [r.geojson for r in q.latest_geometries(LocationsIn(_sids(q, "location"), TimeRange(), None))] == [
            _point(4.0, 1.0).geojson
        ]
    finally:
        with_target.close()


# -- the import graph ---------------------------------------------------------------


def _backend_of(name: str) -> str | None:
    for backend in BACKENDS:
        if name == f"tsdb_service.storage.{backend}" or name.startswith(f"tsdb_service.storage.{backend}."):
            return backend
    return None


def test_shared_storage_code_imports_no_backend():
    for path in sorted(STORAGE.glob("*.py")):
        if path.name == "__init__.py":
            continue  # open_store: the one place that picks a backend
        backends = {b for b in map(_backend_of, module_imports(path)) if b is not None}
        assert not backends, f"{path.name} imports storage.{backends}"


def test_backend_packages_never_import_each_other():
    for backend in BACKENDS:
        for path in sorted((STORAGE / backend).glob("*.py")):
            others = {b for b in map(_backend_of, module_imports(path)) if b not in (None, backend)}
            assert not others, f"{backend}/{path.name} imports storage.{others}"


@pytest.mark.parametrize("backend", BACKENDS)
def test_querier_never_imports_its_store(backend):
    assert f"tsdb_service.storage.{backend}.store" not in module_imports(STORAGE / backend / "querier.py")
