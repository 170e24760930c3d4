"""``Querier.window_scan`` and ``Querier.located_series``: what an NGSI-LD
geo-query with ``q`` reads. DuckDB answers many series' questions in one
statement and finds a type's near series from memory; either must answer
exactly as the one-statement-per-question reads (the seam's defaults,
which PostgreSQL uses). On both backends, before and after DuckDB moves
the rows from its hot table to the sorted one."""

from __future__ import annotations

import random
from datetime import UTC, datetime

import pytest

from tests.ngsild_fixtures import TENANT, ld_notify
from tsdb_service.core.query import EntityFilter, InstanceWindow, Scope, ValueTest
from tsdb_service.geo.filter import BBox
from tsdb_service.read.instances import SeparateScans
from tsdb_service.read.requests import ExtentsNear, LocatedSelect, SeriesSelect, WindowScan

SCOPE = Scope(TENANT)
TIMES = ["2024-01-01T00:00:00Z", "2024-01-01T00:20:00Z", "2024-01-01T00:40:00Z"]
WINDOWS = [
    InstanceWindow(),
    InstanceWindow("observedAt", datetime(2024, 1, 1, 0, 10, tzinfo=UTC), datetime(2024, 1, 1, 0, 50, tzinfo=UTC)),
    InstanceWindow("observedAt", None, datetime(2024, 1, 1, 0, 10, tzinfo=UTC)),
]
BOX = BBox(0.0, 0.0, 0.05, 0.05)  # min_lon, min_lat, max_lon, max_lat
TESTS = [ValueTest(">=", 5.0), ValueTest("<", 2.0), ValueTest("==", "r1"), ValueTest()]


def _store_robots(client) -> None:
    """150 series (50 robots x 3 attributes) at three instants."""
    rng = random.Random(3)
    for at in TIMES:
        robots = []
        for n in range(50):  # 150 series: above DuckDB's per-series branches
            lon, lat = rng.uniform(-0.05, 0.1), rng.uniform(-0.05, 0.1)
            robots.append(
                {
                    "id": f"urn:ngsi-ld:Robot:{n:02d}",
                    "type": "Robot",
                    "speed": {"type": "Property", "value": rng.randrange(10), "observedAt": at},
                    "name": {"type": "Property", "value": f"r{rng.randrange(3)}", "observedAt": at},
                    "location": {
                        "type": "GeoProperty",
                        "observedAt": at,
                        "value": {"type": "Point", "coordinates": [lon, lat]},
                    },
                }
            )
        ld_notify(client, robots)


@pytest.fixture(scope="module")
def hot(client_factory, store_url_factory):
    """The robots as ingested (hot tables), one store per backend; read only."""
    with client_factory(store_url_factory("scan_hot")) as client:
        _store_robots(client)
        yield client.app.state.store


@pytest.fixture(scope="module")
def compacted(client_factory, store_url_factory):
    """The robots after a full compaction (DuckDB sorts them), one store per backend; read only."""
    with client_factory(store_url_factory("scan_sorted")) as client:
        _store_robots(client)
        _compacted(client.app.state.store)
        yield client.app.state.store


@pytest.fixture
def stored(client):
    """The robots on a store of the test's own (it writes)."""
    _store_robots(client)
    return client.app.state.store


def _sids(querier, attr: str) -> list[int]:
    return sorted(r.sid for r in querier.series(SeriesSelect(SCOPE, EntityFilter(types=("Robot",)), [attr])))


def _compacted(store) -> None:
    if hasattr(store, "compact"):
        store.compact(full=True)


@pytest.mark.parametrize("compact", [False, True], ids=["hot", "sorted"])
@pytest.mark.parametrize("window", WINDOWS, ids=["all", "between", "before"])
@pytest.mark.parametrize(
    "prefilter", [None, ("intersects", BOX), ("within", BOX)], ids=["none", "intersects", "within"]
)
def test_one_scan_answers_as_one_statement_each(hot, compacted, compact, window, prefilter):
    q = (compacted if compact else hot).querier()
    locations = (_sids(q, "location"), prefilter)
    tests = [(_sids(q, "speed"), TESTS[0]), (_sids(q, "speed"), TESTS[1]), (_sids(q, "name"), TESTS[2]), ([], TESTS[3])]
    rows, found = q.window_scan(WindowScan(window, locations, tests))
    want_rows, want_found = SeparateScans.window_scan(q, WindowScan(window, locations, tests))
    assert sorted(rows) == sorted(want_rows)
    assert found == want_found
    assert rows and any(found) and not found[3]


def test_without_locations_or_with_one_question(hot):
    q = hot.querier()
    window = WINDOWS[1]
    for locations, tests in [
        (None, [(_sids(q, "speed"), TESTS[0]), (_sids(q, "name"), TESTS[2])]),
        ((_sids(q, "location"), None), []),
        (([], None), [(_sids(q, "speed"), TESTS[1])]),
    ]:
        rows, found = q.window_scan(WindowScan(window, locations, tests))
        want_rows, want_found = SeparateScans.window_scan(q, WindowScan(window, locations, tests))
        assert (sorted(rows), found) == (sorted(want_rows), want_found)  # rows come in no order


@pytest.mark.parametrize(
    "prefilter", [None, ("intersects", BOX), ("within", BOX)], ids=["none", "intersects", "within"]
)
def test_located_series_are_those_the_extents_keep(hot, prefilter):
    q = hot.querier()
    got = q.located_series(LocatedSelect(SCOPE, ["Robot"], ["location"], prefilter))
    want = _located_by_catalogue(q, prefilter)
    assert sorted(r.sid for r in got) == sorted(r.sid for r in want)
    assert 0 < len(got) <= 50
    assert q.located_series(LocatedSelect(SCOPE, ["Robot"], ["speed"], prefilter)) == []  # never located
    assert q.located_series(LocatedSelect(Scope("nobody"), ["Robot"], ["location"], prefilter)) == []


def test_located_series_sees_series_created_since(stored, client):
    """The catalog keeps each (types, attrs) set until new series arrive: a
    robot notified after a first geo-query is found by the next one."""
    q = stored.querier()
    before = {r.entity_id for r in q.located_series(LocatedSelect(SCOPE, ["Robot"], ["location"], ("intersects", BOX)))}
    newcomer = {
        "id": "urn:ngsi-ld:Robot:new",
        "type": "Robot",
        "location": {
            "type": "GeoProperty",
            "observedAt": TIMES[0],
            "value": {"type": "Point", "coordinates": [0.01, 0.01]},
        },
    }
    ld_notify(client, [newcomer])
    after = {
        r.entity_id
        for r in stored.querier().located_series(LocatedSelect(SCOPE, ["Robot"], ["location"], ("intersects", BOX)))
    }
    assert after == before | {"urn:ngsi-ld:Robot:new"}


def _located_by_catalogue(q, prefilter):
    """The plain way to find them: every located series of the type, kept
    where its extent may pass (what the catalog's (types, attrs) set saves)."""
    refs = q.series(SeriesSelect(SCOPE, EntityFilter(types=("Robot",)), ["location"]))
    near = {row[0] for row in q.location_extents(ExtentsNear([r.sid for r in refs], prefilter))}
    return [r for r in refs if r.sid in near]
