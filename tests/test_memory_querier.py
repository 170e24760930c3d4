"""``read.memory.MemoryQuerier`` answers every read of the seam as the SQL
backends do: the same data, stored through notifications on a real backend,
copied row for row into memory, and every kind of read asked of both.

Where the SQL leaves an order open (``GROUP BY``, ``DISTINCT``, rows of one
notification) both answers are sorted before they are compared.
"""

from __future__ import annotations

from datetime import UTC, datetime, timedelta

import pytest

from tests.ngsild_fixtures import TENANT, load_vehicles
from tsdb_service.core.model import instance_urn
from tsdb_service.core.query import (
    AggBranch,
    Aggregation,
    AggrMethod,
    AggrPeriod,
    EntityFilter,
    InstancePeriods,
    InstanceWindow,
    RowMask,
    Scope,
    TimeRange,
    ValueTest,
)
from tsdb_service.geo.filter import BBox
from tsdb_service.read.memory import MemoryQuerier, MemorySample
from tsdb_service.read.requests import (
    AggregateRead,
    ExportRead,
    ExtentsNear,
    InstanceAggregateRead,
    InstanceLocations,
    InstanceLookup,
    InstancePage,
    InstancesIn,
    InstancesMatching,
    InstancesRead,
    LocatedSelect,
    LocationsIn,
    RowsRead,
    SamplesIn,
    SeriesSelect,
    ValuesAt,
    WindowScan,
)

T0 = datetime(2024, 5, 1, 10, 0, tzinfo=UTC)
ROBOTS = Scope("acme")
COLUMNS = (
    "rid, sid, iid, t, kind, atype, num, txt, js, geo, lon, lat, min_lon, min_lat, max_lon, max_lat, md, "
    "observed_at, created_at, modified_at, deleted_at"
)
BOX = BBox(-1.0, -1.0, 0.5, 1.0)


def _robot(i: int, n: int) -> dict:
    lon = -0.5 + 0.25 * i
    return {
        "id": f"Robot:{n}",
        "type": "Robot",
        "TimeInstant": {"type": "DateTime", "value": (T0 + timedelta(minutes=17 * i + n)).isoformat()},
        "speed": {"type": "Number", "value": i * 2 + n if i % 3 else i + 0.5},
        "mode": {"type": "Text", "value": ["idle", "mowing", "docked"][i % 3]},
        "busy": {"type": "Boolean", "value": i % 2 == 0},
        "odom": {"type": "StructuredValue", "value": {"twist": {"x": i, "y": n * 1.5}, "seq": [i, n]}},
        "location": {
            "type": "geo:json",
            "value": {"type": "Point", "coordinates": [lon, 0.1 * n]}
            if i % 4
            else {"type": "Polygon", "coordinates": [[[lon, 0], [lon + 0.1, 0], [lon + 0.1, 0.1], [lon, 0]]]},
        },
    }


@pytest.fixture(scope="module")
def pair(client_factory, store_url_factory):
    """(the backend's querier, a MemoryQuerier holding the same rows)."""
    with client_factory(store_url_factory("memory_pair")) as client:
        for i in range(12):
            for n, path in ((1, "/garden"), (2, "/garden/north"), (3, "/yard")):
                body = {"subscriptionId": "s", "data": [_robot(i, n)]}
                headers = {"Fiware-Service": "acme", "Fiware-ServicePath": path}
                response = client.post("/v2/notify", json=body, headers=headers)
                assert response.status_code == 200, response.text
        load_vehicles(client)
        q = client.app.state.store.querier()
        yield q, _copy(q)


def _copy(q) -> MemoryQuerier:
    memory = MemoryQuerier()
    for tenant in q.tenants():
        for ref in q.series(SeriesSelect(Scope(tenant), EntityFilter())):
            memory.add_series(tenant, ref)
    rows = q._fetch(f"SELECT {COLUMNS} FROM {q.dialect.samples(COLUMNS)}", [])
    memory.add_samples(MemorySample(*row) for row in rows)
    return memory


def _sids(q, scope: Scope = ROBOTS, attrs=None, entities=EntityFilter()) -> list[int]:
    return [r.sid for r in q.series(SeriesSelect(scope, entities, attrs))]


def same(pair, read, ordered: bool = True):
    backend, memory = pair
    got, want = read(memory), read(backend)
    if not ordered:
        got, want = sorted(got, key=repr), sorted(want, key=repr)
    assert got == want
    return want


@pytest.mark.parametrize(
    "ask",
    [
        SeriesSelect(ROBOTS, EntityFilter()),
        SeriesSelect(ROBOTS, EntityFilter(ids=("Robot:2",)), {"speed", "mode"}),
        SeriesSelect(ROBOTS, EntityFilter(id_pattern="Robot:[13]")),
        SeriesSelect(Scope("acme", ("/garden",)), EntityFilter(types=("Robot",))),
        SeriesSelect(Scope(TENANT), EntityFilter(types=("Vehicle",))),
        SeriesSelect(Scope("nobody"), EntityFilter()),
    ],
)
def test_the_catalogue(pair, ask):
    same(pair, lambda q: q.series(ask), ordered=False)


def test_tenants_names_and_live_series(pair):
    same(pair, lambda q: q.tenants())
    same(pair, lambda q: q.series_names(Scope(TENANT)))
    same(pair, lambda q: q.sids_with_samples(_sids(q)))


@pytest.mark.parametrize("one_per_row", [True, False])
@pytest.mark.parametrize("newest_first", [False, True])
@pytest.mark.parametrize(("limit", "offset"), [(5, 0), (7, 3), (1000, 0)])
def test_raw_rows(pair, one_per_row, newest_first, limit, offset):
    attrs = {"speed"} if one_per_row else {"speed", "mode", "busy"}
    time = TimeRange(T0 + timedelta(minutes=20), T0 + timedelta(hours=2))

    def read(q):
        rows = q.raw_rows(RowsRead(_sids(q, attrs=attrs), time, newest_first, limit, offset, one_per_row, len(attrs)))
        return rows if one_per_row else sorted(rows)

    assert same(pair, read)


def test_raw_rows_under_a_mask(pair):
    def read(q):
        sids = _sids(q, attrs={"speed"})
        start = int((T0 - datetime(1970, 1, 1, tzinfo=UTC)).total_seconds() * 1_000_000)
        mask = RowMask({sid: [(start, 0, start + 3_600_000_000, 0)] for sid in sids[:2]})
        return q.raw_rows(RowsRead(sids, TimeRange(), False, 100, 0, True, mask=mask))

    assert same(pair, read)


@pytest.mark.parametrize("method", list(AggrMethod))
@pytest.mark.parametrize("period", [None, AggrPeriod.HOUR, AggrPeriod.DAY])
def test_aggregate(pair, method, period):
    def read(q):
        branches = [
            AggBranch(tuple(_sids(q, attrs={"speed"}))),
            AggBranch(tuple(_sids(q, attrs={"odom"})), ("twist", "y")),
        ]
        return q.aggregate(AggregateRead(branches, TimeRange(), Aggregation(method, period)))

    assert same(pair, read, ordered=False)


def test_latest_last_and_count(pair):
    time = TimeRange(None, T0 + timedelta(hours=1))
    same(pair, lambda q: q.latest_index(SamplesIn(_sids(q), time)), ordered=False)
    same(pair, lambda q: q.last_values(_sids(q)), ordered=False)
    for at in (T0 - timedelta(days=1), T0 + timedelta(minutes=40), T0 + timedelta(days=1)):
        same(pair, lambda q, at=at: q.values_at(ValuesAt(_sids(q), at)), ordered=False)
    assert same(pair, lambda q: q.count(SamplesIn(_sids(q), time))) > 0


@pytest.mark.parametrize("prefilter", [None, ("intersects", BOX), ("within", BOX)])
def test_locations(pair, prefilter):
    located = {"location"}
    window = TimeRange(T0 + timedelta(minutes=30), T0 + timedelta(hours=2))
    same(pair, lambda q: q.latest_geometries(LocationsIn(_sids(q, attrs=located), TimeRange(), prefilter)), False)
    same(pair, lambda q: q.latest_geometries(LocationsIn(_sids(q, attrs=located), window, prefilter)), False)
    same(pair, lambda q: [r[:5] for r in q.location_extents(ExtentsNear(_sids(q, attrs=located), prefilter))], False)
    same(pair, lambda q: q.located_series(LocatedSelect(ROBOTS, ["Robot"], ["location"], prefilter)), False)
    assert same(pair, lambda q: q.first_locations(_sids(q, attrs=located)), False)
    assert same(pair, lambda q: q.location_samples(LocationsIn(_sids(q, attrs=located), window, prefilter)))


WINDOWS = [
    InstanceWindow(),
    InstanceWindow("observedAt", datetime(2018, 8, 1, 12, 4, tzinfo=UTC), datetime(2018, 8, 1, 12, 15, tzinfo=UTC)),
    InstanceWindow("observedAt", None, T0 + timedelta(hours=1)),
]


@pytest.mark.parametrize("window", WINDOWS)
@pytest.mark.parametrize(("last_n", "limit", "newest"), [(None, None, False), (2, None, False), (None, 5, True)])
def test_temporal_instances(pair, window, last_n, limit, newest):
    def read(q):
        sids = _sids(q, Scope(TENANT)) + _sids(q, attrs={"speed", "location"})
        return q.temporal_instances(InstancesRead(sids, window, last_n, limit, newest))

    assert same(pair, read)


@pytest.mark.parametrize("window", WINDOWS)
@pytest.mark.parametrize("ascending", [True, False])
@pytest.mark.parametrize(("offset", "size", "limit"), [(0, 2, 100), (1, 2, 100), (0, None, 5), (2, 1, 3), (9, 3, 10)])
def test_instance_pages(pair, window, ascending, offset, size, limit):
    def read(q):
        sids = _sids(q, Scope(TENANT)) + _sids(q, attrs={"speed", "location"})
        first = q.instance_page(InstancePage(sids, window, ascending, offset, size, limit))
        through = None if first[1] is None else first[1] - 3  # a walk that began before the last instances
        return first, q.instance_page(InstancePage(sids, window, ascending, offset, size, limit, through))

    assert same(pair, read)


def test_spans_narrow_the_series_they_list(pair):
    """``InstanceWindow.spans``: listed series keep the instances inside
    their spans; the others keep the whole window."""

    def read(q):
        sids = _sids(q, Scope(TENANT))
        spans = ((sids[0], datetime(2018, 8, 1, 12, 4, tzinfo=UTC), None), (sids[1], None, T0))
        spans += ((sids[1], datetime(2018, 8, 1, 12, 13, tzinfo=UTC), datetime(2018, 8, 1, 12, 15, tzinfo=UTC)),)
        window = InstanceWindow("observedAt", None, T0, spans)
        return (
            q.temporal_instances(InstancesRead(sids, window)),
            q.instances_matching(InstancesMatching(sids, window, ValueTest())),
            sorted(q.instance_values(InstancesIn(sids, window))),
            q.instance_page(InstancePage(sids, window, True, 0, 1, 100)),
        )

    assert same(pair, read)


@pytest.mark.parametrize("window", WINDOWS)
def test_instance_filters(pair, window):
    vehicles = Scope(TENANT)
    tests = [ValueTest(), ValueTest(">", 70.0), ValueTest("==", "brand1"), ValueTest("<=", 40.0), ValueTest("array")]
    for test in tests:
        same(pair, lambda q, test=test: q.instances_matching(InstancesMatching(_sids(q, vehicles), window, test)))
    assert same(pair, lambda q: q.instance_values(InstancesIn(_sids(q, vehicles), window)), ordered=False)
    for prefilter in (None, ("intersects", BBox(-4.0, 40.0, 0.0, 41.0))):
        same(
            pair,
            lambda q, p=prefilter: q.location_instances(InstanceLocations(_sids(q, vehicles), window, p)),
            ordered=False,
        )

    def scan(q):
        located = (_sids(q, vehicles, {"location"}), None)
        rows, found = q.window_scan(WindowScan(window, located, [(_sids(q, vehicles), t) for t in tests]))
        return sorted(rows), found

    same(pair, scan)
    same(pair, lambda q: q.instance_span(InstancesIn(_sids(q, vehicles), window)))


@pytest.mark.parametrize(
    "periods",
    [
        InstancePeriods(),
        InstancePeriods(step_us=120_000_000),
        InstancePeriods(step_us=3_600_000_000, origin_us=1_533_124_800_000_000),
        InstancePeriods(edges=(1_533_124_800_000_000, 1_533_125_400_000_000, 1_533_126_000_000_000)),
    ],
    ids=["one", "step", "origin", "edges"],
)
def test_instance_aggregate(pair, periods):
    methods = ("totalCount", "distinctCount", "sum", "avg", "min", "max", "stddev", "sumsq")

    def read(q):
        sids = _sids(q, Scope(TENANT))
        rows = q.instance_aggregate(InstanceAggregateRead(sids, InstanceWindow(), methods, periods))
        if periods.step_us or periods.edges:  # the first instance time: a backend may give it anyway
            rows = [(*row[:14], None, row[15]) for row in rows]
        return sorted(tuple("" if v is None else v for v in row) for row in rows)

    assert same(pair, read)


def test_instance_lookup(pair):
    backend, _ = pair
    [row, *_] = backend.temporal_instances(InstancesRead(_sids(backend, Scope(TENANT))))
    same(pair, lambda q: q.instance_at(InstanceLookup(_sids(q, Scope(TENANT)), instance_urn(row.iid))))
    same(pair, lambda q: q.instance_at(InstanceLookup(_sids(q, Scope(TENANT)), "urn:ngsi-ld:Instance:unknown")))


def test_bulk_reads(pair):
    same(pair, lambda q: q.sample_counts())
    same(pair, lambda q: [s for batch in q.stored_samples(50) for s in batch])

    def exported(q):
        with q.export_batches(ExportRead(_sids(q), TimeRange(), 40, 1000)) as batches:
            out = []
            while (columns := batches.next()) is not None:
                times = [v.value if hasattr(v, "value") else v for v in columns[0].to_pylist()]
                out += zip(times, *(c.to_pylist() for c in columns[1:]), strict=True)
        return [(_micros(row[0]), *row[1:]) for row in out]

    assert same(pair, exported, ordered=False)


def _micros(value) -> int:
    """An export's time column: epoch µs (PostgreSQL) or a naive timestamp (DuckDB)."""
    if isinstance(value, int):
        return value
    return (value - datetime(1970, 1, 1)) // timedelta(microseconds=1)
