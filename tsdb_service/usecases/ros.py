"""ROS 2 messages as the ROS 2 IoT Agent forwards them: the message as JSON.

The agent serialises each message field by field (``header.stamp.sec``,
``pose.pose.position.x`` ...), so the history stores exactly these nested
objects and dashboards reach into them with value paths such as
``odom(twist.twist.linear.x)``. Only the fields ROS defines are produced.
"""

from __future__ import annotations

import math
from datetime import datetime

# sensor_msgs/Range.radiation_type
ULTRASOUND = 0
INFRARED = 1


def header(at: datetime, frame_id: str) -> dict:
    """std_msgs/Header: the stamp is the simulated time, split as ROS 2 does."""
    micros = round(at.timestamp() * 1_000_000)
    sec, rest = divmod(micros, 1_000_000)
    return {"stamp": {"sec": sec, "nanosec": rest * 1000}, "frame_id": frame_id}


def scalar(value: float | int | bool) -> dict:
    """std_msgs/Float32, Int32, UInt8, Bool ...: a single ``data`` field."""
    if isinstance(value, float):
        value = round(value, 3)
    return {"data": value}


def vector3(x: float = 0.0, y: float = 0.0, z: float = 0.0) -> dict:
    return {"x": round(x, 4), "y": round(y, 4), "z": round(z, 4)}


def twist(linear_x: float, angular_z: float) -> dict:
    """geometry_msgs/Twist for a ground robot: forward speed and yaw rate."""
    return {"linear": vector3(linear_x), "angular": vector3(z=angular_z)}


def quaternion_from_yaw(yaw: float) -> dict:
    """geometry_msgs/Quaternion of a rotation about z only."""
    return {"x": 0.0, "y": 0.0, "z": round(math.sin(yaw / 2), 6), "w": round(math.cos(yaw / 2), 6)}


def _covariance(diagonal: float) -> list[float]:
    """A 6x6 row-major covariance with the same variance on the diagonal."""
    return [diagonal if row == col else 0.0 for row in range(6) for col in range(6)]


def odometry(
    at: datetime, x: float, y: float, yaw: float, linear_x: float, angular_z: float, frame_id: str = "odom"
) -> dict:
    """nav_msgs/Odometry of a planar robot."""
    return {
        "header": header(at, frame_id),
        "child_frame_id": "base_link",
        "pose": {
            "pose": {"position": vector3(x, y), "orientation": quaternion_from_yaw(yaw)},
            "covariance": _covariance(0.01),
        },
        "twist": {"twist": twist(linear_x, angular_z), "covariance": _covariance(0.001)},
    }


def range_reading(
    at: datetime, distance: float, *, frame_id: str, radiation_type: int, fov: float, min_range: float, max_range: float
) -> dict:
    """sensor_msgs/Range: a distance sensor (ultrasound bumper, laser gate)."""
    return {
        "header": header(at, frame_id),
        "radiation_type": radiation_type,
        "field_of_view": fov,
        "min_range": min_range,
        "max_range": max_range,
        "range": round(min(max(distance, min_range), max_range), 3),
    }
