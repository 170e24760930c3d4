"""The lawnmower's recorded run as a ROS 2 bag: what ``ros2 bag record`` would have kept on the robot.

``write_lawnmower_bag(folder)`` writes ``folder/run/`` (a rosbag2 directory,
MCAP storage) and ``folder/run.map.yaml`` (the map ``tsdb-service import
rosbag`` places it with: the topics become the attributes of the demo's
lawnmower, as the ROS 2 IoT Agent forwards them). The run is the
lawnmower simulator's (``usecases.lawnmower``), seeded and dated, so the
same code writes the same messages: ``tsdb-service notifications build``
writes it into ``notifications/lawnmower/``, a test checks the committed
one is what the code writes, and the demo imports it at start
(``lawnmower_bag``: the committed one in a checkout, else one written next
to the demo's database).

Each topic is published when the simulator updates it: every second,
``cmd_vel`` only while an operator drives. A message's ``header.stamp`` is
the simulated instant; the bag's receive time is 20 ms later (the
import keeps the stamp).
"""

from __future__ import annotations

import math
import random
import shutil
import tempfile
from collections.abc import Iterator
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any

from tsdb_service.usecases import ros, sites
from tsdb_service.usecases.lawnmower import Lawnmower
from tsdb_service.usecases.orion import iso

BAG_START = datetime(2025, 6, 1, 8, 0, tzinfo=UTC)
BAG_SECONDS = 360
BAG_SEED = 1  # a cycle with an operator at the joystick (cmd_vel) within the run
RECEIVE_DELAY_NS = 20_000_000
BAG_NAME, MAP_NAME = "run", "run.map.yaml"

# attribute of the simulator's entity → (topic, ROS message type)
TOPICS = {
    "odom": ("/odom", "nav_msgs/msg/Odometry"),
    "location": ("/gps/fix", "sensor_msgs/msg/NavSatFix"),
    "navigationState": ("/navigation/state", "std_msgs/msg/UInt8"),
    "navigationSubState": ("/navigation/substate", "std_msgs/msg/UInt8"),
    "perimeterLeft": ("/perimeter/left", "std_msgs/msg/Bool"),
    "perimeterRight": ("/perimeter/right", "std_msgs/msg/Bool"),
    "obstacleDistance": ("/sonar/front", "sensor_msgs/msg/Range"),
    "cmd_vel": ("/cmd_vel", "geometry_msgs/msg/Twist"),
}
_NUMPY = {
    "bool": "bool",
    "int8": "i1",
    "uint8": "u1",
    "byte": "u1",
    "char": "u1",
    "int16": "i2",
    "uint16": "u2",
    "int32": "i4",
    "uint32": "u4",
    "int64": "i8",
    "uint64": "u8",
    "float32": "f4",
    "float64": "f8",
}


def map_text() -> str:
    """The import map of the recorded run (YAML)."""
    entity = sites.LAWNMOWER_ID
    lines = [
        "# The lawnmower's recorded run (the ROS 2 bag run/), placed as the ROS 2 IoT Agent forwards it:",
        "# each topic an attribute of the demo's lawnmower, the message as an Object; the GNSS fix as its location.",
        f"service: {sites.LAWNMOWER.service}",
        f"service_path: {sites.LAWNMOWER.service_path}",
        "entity_type: ROS2System",
        "topics:",
    ]
    for attr, (topic, _) in TOPICS.items():
        if attr == "location":
            lines.append(f"  {topic}: {{entity: '{entity}', attributes: {{location: {{path: '', type: geo:json}}}}}}")
        else:
            lines.append(f"  {topic}: {{entity: '{entity}', attribute: {attr}}}")
    return "\n".join(lines) + "\n"


def write_lawnmower_bag(folder: Path) -> list[Path]:
    """Write ``folder/run/`` and ``folder/run.map.yaml`` (replacing them); the files written."""
    from rosbags.rosbag2 import Writer
    from rosbags.rosbag2.enums import StoragePlugin
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    folder.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=folder) as scratch:
        path = Path(scratch) / BAG_NAME
        with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
            connections = {attr: writer.add_connection(t, m, typestore=store) for attr, (t, m) in TOPICS.items()}
            for attr, at, data in recorded_run():
                msgtype = TOPICS[attr][1]
                raw = store.serialize_cdr(message(store, msgtype, data), msgtype)
                writer.write(connections[attr], _ns(at) + RECEIVE_DELAY_NS, raw)
        target = folder / BAG_NAME
        if target.exists():
            shutil.rmtree(target)
        path.rename(target)
    (folder / MAP_NAME).write_text(map_text())
    return [*sorted(target.iterdir()), folder / MAP_NAME]


def recorded_run() -> Iterator[tuple[str, datetime, dict]]:
    """(attribute, instant, ROS message as JSON data) of every message of the run, in time order."""
    end = BAG_START + timedelta(seconds=BAG_SECONDS)
    for emission in Lawnmower().emissions(BAG_START, random.Random(BAG_SEED)):
        if emission.at > end:
            return
        stamp = iso(emission.at)
        for attr in TOPICS:
            item = emission.entity.get(attr)
            if item is None or item["metadata"]["TimeInstant"]["value"] != stamp:
                continue  # not published at this instant
            yield attr, emission.at, _ros(attr, item["value"], emission.at)


def _ros(attr: str, value: Any, at: datetime) -> dict:
    """The simulator's attribute value as the ROS message it was published as."""
    if attr == "location":
        lon, lat = value["coordinates"][:2]
        return {
            "header": ros.header(at, "gps"),
            "status": {"status": 0, "service": 1},  # STATUS_FIX, SERVICE_GPS
            "latitude": lat,
            "longitude": lon,
            "altitude": math.nan,  # the mower's receiver gives none
            "position_covariance": [0.09 if r == c else 0.0 for r in range(3) for c in range(3)],
            "position_covariance_type": 2,  # DIAGONAL_KNOWN
        }
    return value


def message(store, msgtype: str, data: dict):
    """A rosbags message object of ``msgtype`` from its JSON data (the shape
    ``usecases.ros`` and the ROS 2 IoT Agent use)."""
    import numpy as np
    from rosbags.typesys.store import Nodetype

    fields: dict[str, Any] = {}
    for name, (node, detail) in store.fielddefs[msgtype][1]:
        value = data[name]
        if node == Nodetype.NAME:
            fields[name] = message(store, detail, value)
        elif node == Nodetype.BASE:
            fields[name] = value
        else:
            inner, inner_detail = detail[0]
            if inner == Nodetype.NAME:
                fields[name] = [message(store, inner_detail, item) for item in value]
            elif inner_detail[0] in _NUMPY:
                fields[name] = np.array(value, dtype=_NUMPY[inner_detail[0]])
            else:
                fields[name] = list(value)
    return store.types[msgtype](**fields)


def lawnmower_bag(db: str) -> Path:
    """The folder holding the recorded run and its map: the checkout's
    ``notifications/lawnmower``, else written (once) next to ``db``."""
    checkout = Path(__file__).resolve().parents[2] / "notifications" / "lawnmower"
    if (checkout / BAG_NAME / "metadata.yaml").exists() and (checkout / MAP_NAME).exists():
        return checkout
    folder = Path(db).with_suffix(".demo-bag") if "://" not in db else Path(tempfile.gettempdir()) / "tsdb-demo-bag"
    if not (folder / BAG_NAME / "metadata.yaml").exists():
        write_lawnmower_bag(folder)
    return folder


def _ns(at: datetime) -> int:
    delta = at - datetime(1970, 1, 1, tzinfo=UTC)
    return (delta.days * 86_400 + delta.seconds) * 1_000_000_000 + delta.microseconds * 1000
