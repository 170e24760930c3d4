"""The demo's recorded run: the lawnmower as a ROS 2 bag in ``notifications/lawnmower/``.

Written by the project's own generator (``demo.bag``, through ``tsdb-service
notifications build``): the committed bag is byte for byte what the code
writes, it stays small, and its map imports it into the demo's lawnmower
as the ROS 2 IoT Agent would have forwarded it.
"""

from __future__ import annotations

from collections import Counter
from datetime import datetime
from pathlib import Path

from tsdb_service.commands.rosbag.importer import import_rosbag
from tsdb_service.commands.rosbag.mapping import load_map
from tsdb_service.core.config import Settings
from tsdb_service.demo.bag import BAG_NAME, BAG_SECONDS, BAG_START, MAP_NAME, TOPICS, recorded_run, write_lawnmower_bag
from tsdb_service.usecases import sites

COMMITTED = Path(__file__).resolve().parents[1] / "notifications" / "lawnmower"


def test_the_committed_bag_is_what_the_generator_writes(tmp_path):
    for path in write_lawnmower_bag(tmp_path):
        committed = COMMITTED / path.relative_to(tmp_path)
        assert committed.exists(), f"{committed} is missing: run `tsdb-service notifications build`"
        assert committed.read_bytes() == path.read_bytes(), (
            f"{committed} is stale: run `tsdb-service notifications build`"
        )


def test_the_bag_is_small():
    size = sum(p.stat().st_size for p in (COMMITTED / BAG_NAME).iterdir())
    assert size < 1024 * 1024, size


def test_the_run_mows_and_an_operator_drives():
    published = Counter(attr for attr, _, _ in recorded_run())
    assert published["odom"] == BAG_SECONDS  # once a second
    assert set(published) == set(TOPICS) and published["cmd_vel"] > 10


def test_its_map_places_it_in_the_demo_lawnmower(tmp_path, client_factory):
    from tsdb_service.storage import open_store

    db = str(tmp_path / "t.duckdb")
    store = open_store(Settings(db=db))
    try:
        report = import_rosbag(COMMITTED / BAG_NAME, store, spec=load_map(COMMITTED / MAP_NAME))
    finally:
        store.close()
    assert report.messages == sum(1 for _ in recorded_run()) and report.rejected == report.unstamped == 0
    headers = {"Fiware-Service": sites.LAWNMOWER.service, "Fiware-ServicePath": sites.LAWNMOWER.service_path}
    with client_factory(db) as client:
        base = f"/v2/entities/{sites.LAWNMOWER_ID}/attrs"
        odom = client.get(f"{base}/odom", headers=headers).json()
        times = [datetime.fromisoformat(t) for t in odom["index"]]
        assert times[0] == BAG_START.replace(second=1) and (times[-1] - BAG_START).total_seconds() == BAG_SECONDS
        location = client.get(f"{base}/location", headers=headers, params={"lastN": 1}).json()["values"][0]
        lon, lat = location["coordinates"]
        assert abs(lat - sites.GARDEN_ORIGIN[0]) < 0.001 and abs(lon - sites.GARDEN_ORIGIN[1]) < 0.001
        speed = client.get(f"{base}/odom(twist.twist.linear.x)", headers=headers, params={"aggrMethod": "max"}).json()
        assert 0.3 < speed["values"][0] < 0.6
