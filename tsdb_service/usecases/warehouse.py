"""PIAP smart warehouse: a robot passes an automated door, again and again.

The robot starts 3 m before the door, drives through it and stops 3 m past it,
waits, and comes back the other way. A laser gate at the door measures the
robot's distance (with Gaussian noise); the door controller opens the door
when that *measured* distance is under 60 cm and closes it as soon as it is
not, so every stored sample obeys the rule the controller saw. The warning
light is on whenever the door is not closed. Humidity and temperature drift
slowly with Gaussian noise.

Two ROS 2 systems, one entity each:

* ``urn:ngsiv2:ROS2System:PiapWarehouse01``: ``laserDistance``
  (sensor_msgs/Range), ``temperature`` and ``humidity`` (std_msgs/Float32),
  ``doorState``, ``doorCommand``, ``warningLight``, ``warningLightCommand``
  (std_msgs/UInt8, see enums), every 0.5 s;
* ``urn:ngsiv2:ROS2System:PiapRobot01``: ``odom`` (nav_msgs/Odometry), every 1 s.
"""

from __future__ import annotations

import math
import random
from collections.abc import Iterator
from dataclasses import dataclass
from datetime import datetime, timedelta

from tsdb_service.usecases import ros, sites
from tsdb_service.usecases.base import Emission, Simulator
from tsdb_service.usecases.enums import DOOR_COMMAND, DOOR_STATE, WARNING_LIGHT_COMMAND, WARNING_LIGHT_STATE, code
from tsdb_service.usecases.orion import EntityState

TICK_S = 0.5
ROBOT_EVERY = 2  # ticks between robot odometry updates
ROBOT_SPEED = 0.2  # m/s
RUN_M = 3.0  # the robot starts and stops this far from the door
DOOR_TRAVEL_S = 1.5  # closed to open
LASER_SIGMA = 0.01  # m


@dataclass
class _Door:
    """Door leaf position from 0 (closed) to 1 (open), and the command it executes."""

    position: float = 0.0
    command: str = "idle"

    def control(self, measured: float) -> None:
        """The controller's rule: open under 60 cm, close otherwise, idle once closed."""
        if measured < sites.DOOR_OPEN_DISTANCE_M:
            self.command = "open"
        elif self.position > 0.0:
            self.command = "close"
        else:
            self.command = "idle"
        step = TICK_S / DOOR_TRAVEL_S
        if self.command == "open":
            self.position = min(1.0, self.position + step)
        elif self.command == "close":
            self.position = max(0.0, self.position - step)

    @property
    def state(self) -> str:
        if self.position <= 0.0:
            return "closed"
        return "open" if self.position >= 1.0 else "in motion"


class Warehouse(Simulator):
    name = "warehouse"
    title = "PIAP smart warehouse"
    tenancy = sites.WAREHOUSE
    subjects = (("^urn:ngsiv2:ROS2System:Piap", "ROS2System"),)

    def emissions(self, start: datetime, rng: random.Random) -> Iterator[Emission]:
        return _Site(start, rng).run()


class _Site:
    def __init__(self, start: datetime, rng: random.Random):
        self.t, self.rng, self.tick = start, rng, 0
        self.x, self.direction = -RUN_M, 1  # robot position along its path; the door is at 0
        self.door = _Door()
        self.temperature, self.humidity = 19.0, 45.0
        self.system = EntityState(sites.WAREHOUSE_ID, "ROS2System")
        self.robot = EntityState(sites.WAREHOUSE_ROBOT_ID, "ROS2System")

    def run(self) -> Iterator[Emission]:
        while True:
            yield from self._wait(self.rng.uniform(4.0, 8.0))
            yield from self._pass()
            self.direction = -self.direction

    def _wait(self, seconds: float) -> Iterator[Emission]:
        for _ in range(round(seconds / TICK_S)):
            yield from self._tick(0.0)

    def _pass(self) -> Iterator[Emission]:
        """Drive from one side, 3 m from the door, to 3 m past it."""
        for _ in range(round(2 * RUN_M / (ROBOT_SPEED * TICK_S))):
            yield from self._tick(ROBOT_SPEED)
        self.x = self.direction * RUN_M  # no drift accumulates over the repeats

    def _tick(self, speed: float) -> Iterator[Emission]:
        self.t += timedelta(seconds=TICK_S)
        self.tick += 1
        self.x += self.direction * speed * TICK_S
        laser = ros.range_reading(
            self.t,
            abs(self.x) + self.rng.gauss(0.0, LASER_SIGMA),
            frame_id="door_laser",
            radiation_type=ros.INFRARED,
            fov=0.02,
            min_range=0.05,
            max_range=8.0,
        )
        self.door.control(laser["range"])  # the published reading, so stored data obeys the rule
        self._drift_environment()
        self._publish_system(laser)
        yield Emission(self.t, self.system.snapshot(self.t))
        if self.tick % ROBOT_EVERY == 0:
            yaw = 0.0 if self.direction > 0 else math.pi
            odom = ros.odometry(self.t, self.x, self.rng.gauss(0.0, 0.01), yaw, speed, 0.0, frame_id="map")
            self.robot.set("odom", "Object", odom, self.t)
            yield Emission(self.t, self.robot.snapshot(self.t))

    def _drift_environment(self) -> None:
        """A slow random walk held near typical indoor values."""
        self.temperature += 0.02 * (19.0 - self.temperature) + self.rng.gauss(0.0, 0.02)
        self.humidity += 0.02 * (45.0 - self.humidity) + self.rng.gauss(0.0, 0.05)

    def _publish_system(self, laser: dict) -> None:
        t, rng, s, door = self.t, self.rng, self.system, self.door
        s.set("laserDistance", "Object", laser, t)
        s.set("temperature", "Object", ros.scalar(self.temperature + rng.gauss(0.0, 0.1)), t)
        s.set("humidity", "Object", ros.scalar(self.humidity + rng.gauss(0.0, 0.5)), t)
        s.set("doorState", "Object", ros.scalar(code(DOOR_STATE, door.state)), t)
        s.set("doorCommand", "Object", ros.scalar(code(DOOR_COMMAND, door.command)), t)
        light = "off" if door.state == "closed" else "on"
        s.set("warningLight", "Object", ros.scalar(code(WARNING_LIGHT_STATE, light)), t)
        s.set("warningLightCommand", "Object", ros.scalar(code(WARNING_LIGHT_COMMAND, light)), t)
