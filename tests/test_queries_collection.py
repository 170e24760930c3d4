"""The request collection runs green against demo data, and its files are current.

A server subprocess on a temporary DuckDB file is fed a short seeded demo;
then every request of ``tsdb_service.demo.collection`` is executed with its
own checks, exactly as ``tsdb-service queries run`` does. The only tolerated
failures are geo ones, marked xfail with the reason: a geo request answered
"not supported" while the geo-query issue is open, and the per-sample geo
request the entity-level geo semantics cannot answer (see PER_SAMPLE_GEO).
"""

from __future__ import annotations

import asyncio
import json
import re
from datetime import UTC, datetime
from pathlib import Path

import httpx
import pytest

from tests.support.demo_feed import feed_phases
from tests.support.server import ServerProcess
from tsdb_service.cli.demo import write_collection
from tsdb_service.demo import collection
from tsdb_service.demo.collection import QUERIES, Query, by_name, execute
from tsdb_service.usecases import sites

ROOT = Path(__file__).resolve().parents[1]

SEED = 7
PHASES = {"lawnmower": (60.0, 6.0), "warehouse": (30.0, 6.0), "drone": (600.0, 8.0)}
REQUIRED = (
    "List the first N sampled values",
    "List N sampled values at an offset",
    "List the latest N sampled values",
    "Latest N of devices near a point",
    "Latest N of devices in an area",
    "Warehouse: door state history",
    "Drone: positions inside the sensor field",
    "Lawnmower: linear speed",
)


async def _feed(url: str) -> None:
    """Each phase through the demo's runner on virtual time, ending now."""
    stats = await feed_phases(url, PHASES, seed=SEED, end=datetime.now(UTC))
    for row in stats.values():
        assert row.failed == 0, row


@pytest.fixture(scope="module")
def service(store_url_factory):
    with ServerProcess(store_url_factory("collection")) as server:
        asyncio.run(_feed(server.url))
        with httpx.Client(base_url=server.url, timeout=30.0) as client:
            yield server.url, client


# Requests that need a geo filter applied to each sample, not to the entity.
# Issue 4 chose entity semantics (tsdb_service/history/geo_matching.py: an entity
# matches by its *latest* location), so a georel on the moving drone returns
# its whole recent track when it is over the field now, and nothing otherwise.
PER_SAMPLE_GEO: set[str] = set()


def _geo_pending(query: Query, outcome) -> str | None:
    """Why a geo request cannot pass yet, or None: the server refuses geo
    parameters (issue 4 not merged), or the request needs per-sample matching."""
    if query.geo and outcome.status == 400 and "not supported" in outcome.detail.lower():
        return f"geo queries (georel/geometry/coords, issue 4) not implemented yet; server said: {outcome.detail}"
    if query.name in PER_SAMPLE_GEO and outcome.status == 200 and not outcome.ok:
        return (
            "needs per-sample geo matching; the geo API matches an entity by its latest location, "
            f"so positions outside the area come back too: {outcome.detail[:200]}"
        )
    return None


@pytest.mark.parametrize("query", QUERIES, ids=[q.name for q in QUERIES])
def test_every_request_passes(service, query):
    _, client = service
    outcome = execute(client, query, dict(collection.VARIABLES))
    if (pending := _geo_pending(query, outcome)) is not None:
        pytest.xfail(pending)
    assert outcome.ok, f"{query.name}: {outcome.detail}"


def test_offset_pages_through_the_first_values(service):
    _, client = service
    variables = dict(collection.VARIABLES)
    first = execute(client, by_name("List the first N sampled values"), variables).body
    page = execute(client, by_name("List N sampled values at an offset"), variables).body
    source = by_name("List the first N sampled values")
    wider = client.get(source.path, params={"limit": 10}, headers=source.headers()).json()
    assert first["index"] == wider["index"][:5]
    assert page["index"] == wider["index"][5:10] and page["values"] == wider["values"][5:10]


def test_latest_values_are_the_newest(service):
    _, client = service
    query = by_name("List the latest N sampled values")
    latest = execute(client, query, dict(collection.VARIABLES)).body
    everything = client.get(query.path, headers=query.headers()).json()
    assert latest["index"] == everything["index"][-5:]


def test_queries_run_command_prints_a_line_per_request(service, capsys):
    from tsdb_service.cli.main import main

    url, _ = service
    assert main(["queries", "run", "--url", url, "--only", "lawnmower"]) == 0
    out = capsys.readouterr().out
    lines = [line for line in out.splitlines() if line.startswith(("PASS", "FAIL"))]
    assert len(lines) == len(collection.matching("lawnmower")) >= 4
    assert all(line.startswith("PASS") for line in lines), out


# -- the files ------------------------------------------------------------------------


def test_the_collection_has_the_requests_people_ask_for():
    names = [q.name for q in QUERIES]
    assert len(names) == len(set(names)), "request names must be unique"
    for name in REQUIRED:
        assert name in names
    assert any(q.name.startswith("Sum") for q in QUERIES)
    assert any(q.name.startswith("Min") for q in QUERIES)
    assert any(q.name.startswith("Max") for q in QUERIES)
    assert "odom(twist.twist.linear.x)" in by_name("Lawnmower: linear speed").path
    near = dict(by_name("Latest N of devices near a point").params)
    assert re.fullmatch(r"near;maxDistance:\d+", near["georel"]) and near["geometry"] == "point"
    area = dict(by_name("Latest N of devices in an area").params)
    assert area["georel"] == "coveredBy" and area["geometry"] == "polygon"
    ring = [tuple(map(float, p.split(","))) for p in area["coords"].split(";")]
    assert ring[0] == ring[-1], "polygons must be closed"


def test_files_are_generated_from_the_one_source(tmp_path):
    for path in write_collection(tmp_path):
        committed = ROOT / "queries" / path.name
        assert committed.exists(), f"{committed} is missing: run `tsdb-service queries build`"
        assert committed.read_bytes() == path.read_bytes(), f"{committed} is stale: run `tsdb-service queries build`"


def test_postman_collection_is_v2_1_with_a_test_per_request():
    doc = json.loads((ROOT / "queries" / "tsdb-service.postman_collection.json").read_text())
    assert doc["info"]["schema"] == collection.POSTMAN_SCHEMA
    assert {v["key"] for v in doc["variable"]} == set(collection.VARIABLES)
    items = [item for folder in doc["item"] for item in folder["item"]]
    assert [item["name"] for item in items] == [q.name for q in QUERIES], "folders keep the collection's order"
    for item, query in zip(items, QUERIES, strict=True):
        request = item["request"]
        assert request["url"]["raw"].startswith(("{{baseUrl}}/v2/", "{{baseUrl}}/grafana/", "{{baseUrl}}/ngsi-ld/v1/"))
        assert {h["key"]: h["value"] for h in request["header"]} == query.headers()
        script = "\n".join(item["event"][0]["script"]["exec"])
        assert item["event"][0]["listen"] == "test" and "pm.test(" in script
        for check in query.checks:
            assert json.dumps(check.path) in script


def test_http_file_has_one_block_per_request():
    text = (ROOT / "queries" / "tsdb-service.http").read_text()
    blocks = re.findall(r"^### (.+)$", text, flags=re.M)
    assert blocks == [q.name for q in QUERIES]
    assert "@baseUrl = http://localhost:8668" in text
    assert text.count("Fiware-Service: ") == len(QUERIES)


def test_javascript_checks_cover_every_python_check():
    for kind in collection._FAILURES:
        assert f'case "{kind}"' in collection._JS_HELPERS


# -- the checks themselves --------------------------------------------------------------


def test_select_walks_lists_and_alternative_keys():
    doc = {"entities": [{"entityId": "a", "values": [1, 2]}, {"id": "b", "values": [3]}]}
    assert collection.select(doc, "entities.*.id|entityId") == ["a", "b"]
    assert collection.select(doc, "entities.*.values") == [1, 2, 3]
    assert collection.select(doc, "missing.path") == []


def test_checks_fail_on_wrong_answers():
    assert collection.count("values", 1, 2).failure({"values": []})
    assert collection.count("values", 1, 2).failure({"values": [1, 2, 3]})
    assert collection.each_in("values", [0, 1]).failure({"values": [0, 4]})
    assert collection.between("values", 0, 1).failure({"values": [0.5, "x"]})
    assert collection.ascending("index").failure({"index": ["b", "a"]})
    outside = {"type": "Point", "coordinates": [sites.DRONE_HOME[1], sites.DRONE_HOME[0]]}
    assert collection.inside("values", sites.SENSOR_FIELD).failure({"values": [outside]})
    lat, lon = sites.SENSORS[0][1]
    assert (
        collection.inside("values", sites.SENSOR_FIELD).failure(
            {"values": [{"type": "Point", "coordinates": [lon, lat]}]}
        )
        is None
    )
