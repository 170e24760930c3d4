"""ROS bags written by the tests, with rosbags (the library the import reads them with).

``write_bag(path, storage)`` writes a small recording of a robot: standard
messages (``sensor_msgs/NavSatFix``, ``nav_msgs/Odometry``,
``sensor_msgs/BatteryState``, ``geometry_msgs/Twist``, which has no header)
and one custom message (``mower_msgs/msg/BladeStatus``, defined only in the
bag), and returns what it wrote: per topic, each message's receive time (ns),
its stamp (ns, or None) and the message as the import must store it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from rosbags.rosbag2 import Writer
from rosbags.rosbag2.enums import StoragePlugin
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

START_S = 1_714_557_600  # 2024-05-01T10:00:00Z
CUSTOM_TYPE = "mower_msgs/msg/BladeStatus"
CUSTOM_DEFINITION = """\
uint8 IDLE=0
uint8 CUTTING=1
std_msgs/Header header
string mode
float32[] blade_rpm
uint8 state
bool blocked
"""
TOPICS = {
    "/fix": "sensor_msgs/msg/NavSatFix",
    "/odom": "nav_msgs/msg/Odometry",
    "/battery": "sensor_msgs/msg/BatteryState",
    "/cmd_vel": "geometry_msgs/msg/Twist",
    "/blade": CUSTOM_TYPE,
}


@dataclass(frozen=True)
class Written:
    topic: str
    receive_ns: int
    stamp_ns: int | None
    message: dict  # as JSON data, the way the import stores it


def typestore():
    store = get_typestore(Stores.ROS2_HUMBLE)
    store.register(get_types_from_msg(CUSTOM_DEFINITION, CUSTOM_TYPE))
    return store


def write_bag(
    path: Path, storage: str = "sqlite3", count: int = 6, topics: dict[str, str] | None = None
) -> list[Written]:
    """A rosbag2 directory at ``path`` with ``count`` messages per topic;
    what was written, in the import's order (receive time, then topic)."""
    store = typestore()
    plugin = StoragePlugin.SQLITE3 if storage == "sqlite3" else StoragePlugin.MCAP
    written: list[Written] = []
    chosen = topics or TOPICS
    with Writer(path, version=9, storage_plugin=plugin) as writer:
        connections = {t: writer.add_connection(t, m, typestore=store) for t, m in chosen.items()}
        for i in range(count):
            for topic, msgtype in sorted(chosen.items()):
                stamp_ns = (START_S + i) * 10**9 + 250_000_000 + 1234 * (1 + list(chosen).index(topic))
                receive_ns = (START_S + i) * 10**9 + 500_000_000
                obj, plain = MESSAGES[msgtype](store, i, stamp_ns)
                writer.write(connections[topic], receive_ns, store.serialize_cdr(obj, msgtype))
                stamped = "header" in plain and plain["header"]["stamp"] != {"sec": 0, "nanosec": 0}
                written.append(Written(topic, receive_ns, stamp_ns if stamped else None, plain))
    return sorted(written, key=lambda w: (w.receive_ns, w.topic))


def _header(store, stamp_ns: int, frame: str):
    sec, nanosec = divmod(stamp_ns, 10**9)
    header = store.types["std_msgs/msg/Header"](
        stamp=store.types["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec), frame_id=frame
    )
    return header, {"stamp": {"sec": sec, "nanosec": nanosec}, "frame_id": frame}


def _fix(store, i: int, stamp_ns: int):
    header, plain_header = _header(store, stamp_ns, "gps")
    lat, lon = 48.1 + i * 1e-5, 11.5 + i * 2e-5
    covariance = [0.5 if row == col else 0.0 for row in range(3) for col in range(3)]
    status = store.types["sensor_msgs/msg/NavSatStatus"](status=0, service=1)
    obj = store.types["sensor_msgs/msg/NavSatFix"](
        header=header,
        status=status,
        latitude=lat,
        longitude=lon,
        altitude=520.25 if i % 2 else math.nan,
        position_covariance=np.array(covariance),
        position_covariance_type=2,
    )
    plain = {
        "header": plain_header,
        "status": {"status": 0, "service": 1},
        "latitude": lat,
        "longitude": lon,
        "altitude": 520.25 if i % 2 else None,  # NaN is JSON null
        "position_covariance": covariance,
        "position_covariance_type": 2,
    }
    return obj, plain


def _vector(store, x: float, y: float, z: float):
    return store.types["geometry_msgs/msg/Vector3"](x=x, y=y, z=z), {"x": x, "y": y, "z": z}


def _odom(store, i: int, stamp_ns: int):
    t = store.types
    header, plain_header = _header(store, stamp_ns, "odom")
    covariance = [float(k % 7) / 10 for k in range(36)]
    linear, plain_linear = _vector(store, 0.25 * i, 0.0, 0.0)
    angular, plain_angular = _vector(store, 0.0, 0.0, -0.5)
    obj = t["nav_msgs/msg/Odometry"](
        header=header,
        child_frame_id="base_link",
        pose=t["geometry_msgs/msg/PoseWithCovariance"](
            pose=t["geometry_msgs/msg/Pose"](
                position=t["geometry_msgs/msg/Point"](x=1.5 * i, y=-2.0, z=0.0),
                orientation=t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
            ),
            covariance=np.array(covariance),
        ),
        twist=t["geometry_msgs/msg/TwistWithCovariance"](
            twist=t["geometry_msgs/msg/Twist"](linear=linear, angular=angular), covariance=np.array(covariance)
        ),
    )
    plain = {
        "header": plain_header,
        "child_frame_id": "base_link",
        "pose": {
            "pose": {
                "position": {"x": 1.5 * i, "y": -2.0, "z": 0.0},
                "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0},
            },
            "covariance": covariance,
        },
        "twist": {"twist": {"linear": plain_linear, "angular": plain_angular}, "covariance": covariance},
    }
    return obj, plain


def _battery(store, i: int, stamp_ns: int):
    # An unstamped message (header left zero) every third time: stored at its receive time.
    header, plain_header = _header(store, 0 if i % 3 == 2 else stamp_ns, "battery")
    percentage = 0.9 - 0.01 * i
    cells = [3.75, 3.5]
    fields = {
        "voltage": 25.25,
        "temperature": 31.5,
        "current": -1.5,
        "charge": 2.5,
        "capacity": 5.0,
        "design_capacity": 5.0,
        "percentage": percentage,
        "power_supply_status": 2,
        "power_supply_health": 1,
        "power_supply_technology": 2,
        "present": True,
    }
    obj = store.types["sensor_msgs/msg/BatteryState"](
        header=header,
        **fields,
        cell_voltage=np.array(cells, dtype=np.float32),
        cell_temperature=np.array([], dtype=np.float32),
        location="slot0",
        serial_number="BAT-1",
    )
    # float32 fields read back as the doubles of their float32 values.
    f32 = {k: float(np.float32(v)) if isinstance(v, float) else v for k, v in fields.items()}
    plain = {
        "header": plain_header,
        **{k: f32[k] for k in ("voltage", "temperature", "current", "charge", "capacity", "design_capacity")},
        "percentage": f32["percentage"],
        "power_supply_status": 2,
        "power_supply_health": 1,
        "power_supply_technology": 2,
        "present": True,
        "cell_voltage": cells,
        "cell_temperature": [],
        "location": "slot0",
        "serial_number": "BAT-1",
    }
    return obj, plain


def _twist(store, i: int, stamp_ns: int):
    linear, plain_linear = _vector(store, 0.5, 0.0, 0.0)
    angular, plain_angular = _vector(store, 0.0, 0.0, 0.25 * (i % 3))
    return store.types["geometry_msgs/msg/Twist"](linear=linear, angular=angular), {
        "linear": plain_linear,
        "angular": plain_angular,
    }


def _blade(store, i: int, stamp_ns: int):
    header, plain_header = _header(store, stamp_ns, "blade")
    rpm = [2500.5, 2499.25]
    obj = store.types[CUSTOM_TYPE](
        header=header,
        mode="cut" if i % 2 else "idle",
        blade_rpm=np.array(rpm, dtype=np.float32),
        state=i % 2,
        blocked=False,
    )
    plain = {
        "header": plain_header,
        "mode": "cut" if i % 2 else "idle",
        "blade_rpm": rpm,
        "state": i % 2,
        "blocked": False,
    }
    return obj, plain


MESSAGES = {
    "sensor_msgs/msg/NavSatFix": _fix,
    "nav_msgs/msg/Odometry": _odom,
    "sensor_msgs/msg/BatteryState": _battery,
    "geometry_msgs/msg/Twist": _twist,
    CUSTOM_TYPE: _blade,
}
