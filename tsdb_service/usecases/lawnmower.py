"""Bosch lawnmower: a mowing cycle as the ROS 2 IoT Agent reports it, once a second.

The mower charges in its dock, backs out, mows the garden in meanders (straight
lanes, turning when a perimeter coil crosses the border wire or when the
ultrasound sees an obstacle), sometimes hands over to an operator who drives
it by remote control (``cmd_vel`` velocity commands), and follows the border
wire home. Physics are a unicycle model in local metres (x east, y north,
yaw counter-clockwise from east, as REP 103); GPS adds metre-level noise.

Entity ``urn:ngsiv2:ROS2System:Lawnmower01``, one ``Object`` attribute per topic:
``odom`` (nav_msgs/Odometry), ``location`` (geo:json, from the GNSS fix),
``navigationState`` / ``navigationSubState`` (std_msgs/UInt8, see enums),
``perimeterLeft`` / ``perimeterRight`` (std_msgs/Bool), ``obstacleDistance``
(sensor_msgs/Range) and, once an operator has driven it, ``cmd_vel``
(geometry_msgs/Twist).
"""

from __future__ import annotations

import math
import random
from collections.abc import Iterator
from datetime import datetime, timedelta

from tsdb_service.usecases import ros, sites
from tsdb_service.usecases.base import Emission, Simulator
from tsdb_service.usecases.enums import LAWNMOWER_NAVIGATION_STATE as STATE
from tsdb_service.usecases.enums import LAWNMOWER_NAVIGATION_SUBSTATE as SUBSTATE
from tsdb_service.usecases.enums import code
from tsdb_service.usecases.orion import EntityState

TICK_S = 1.0
MOW_SPEED = 0.4  # m/s
TURN_RATE = 0.8  # rad/s
LANE_WIDTH = 0.5  # m
DOCK = (0.5, 0.3)  # local metres; the mower sits in it heading south
SONAR_MAX = 3.0
COIL_AHEAD, COIL_SIDE = 0.25, 0.15  # perimeter coils, relative to the centre


class Lawnmower(Simulator):
    name = "lawnmower"
    title = "Bosch lawnmower"
    tenancy = sites.LAWNMOWER
    subjects = (("^urn:ngsiv2:ROS2System:Lawnmower", "ROS2System"),)

    def emissions(self, start: datetime, rng: random.Random) -> Iterator[Emission]:
        return _Mower(start, rng).run()


class _Mower:
    """The mower's physical state; each motion primitive yields one emission per tick."""

    def __init__(self, start: datetime, rng: random.Random):
        self.t, self.rng = start, rng
        self.x, self.y, self.yaw = DOCK[0], DOCK[1], -math.pi / 2
        self.obstacle: tuple[float, float] | None = None
        self.entity = EntityState(sites.LAWNMOWER_ID, "ROS2System")

    def run(self) -> Iterator[Emission]:
        while True:
            yield from self._charge()
            yield from self._leave_dock()
            yield from self._mow(lanes=self.rng.randint(6, 12))
            if self.rng.random() < 0.6:
                yield from self._remote_control(seconds=self.rng.uniform(40, 90))
            yield from self._return_to_dock()

    # -- phases

    def _charge(self) -> Iterator[Emission]:
        for _ in range(round(self.rng.uniform(30, 60) / TICK_S)):
            yield self._step(0.0, 0.0, "docked", "charging")

    def _leave_dock(self) -> Iterator[Emission]:
        for _ in range(3):  # back out 0.6 m
            yield self._step(-0.2, 0.0, "leaving dock", "driving straight")
        yield from self._turn(math.pi / 2, "leaving dock")

    def _mow(self, lanes: int) -> Iterator[Emission]:
        """Meanders: a straight lane until the wire or an obstacle, then a U-turn."""
        for _ in range(lanes):
            if self.y + LANE_WIDTH + COIL_AHEAD >= sites.GARDEN_DEPTH_M:
                break  # the garden is done
            self._maybe_place_obstacle()
            yield from self._lane()
            heading_east = math.cos(self.yaw) > 0
            turn = math.pi / 2 if heading_east else -math.pi / 2
            yield from self._turn(turn, "mowing")
            yield from self._straight(LANE_WIDTH, "mowing", "turning")
            yield from self._turn(turn, "mowing")
            self.yaw = 0.0 if not heading_east else math.pi  # re-aligned by the wire

    def _lane(self) -> Iterator[Emission]:
        for _ in range(200):  # a lane is at most the garden's width
            left, right = self._coils_out()
            if left or right:
                yield self._step(0.0, 0.0, "mowing", "perimeter detected", left=left, right=right)
                return
            if self._obstacle_distance() < 0.35:
                self.obstacle = None  # it is behind us once we have turned
                yield self._step(0.0, 0.0, "mowing", "avoiding obstacle")
                return
            drift = self.rng.gauss(0.0, 0.01)
            yield self._step(MOW_SPEED, drift, "mowing", "driving straight")

    def _remote_control(self, seconds: float) -> Iterator[Emission]:
        """An operator drives with a joystick: a new command every ~5 s."""
        command = (0.0, 0.0)
        for tick in range(round(seconds / TICK_S)):
            if tick % 5 == 0:
                command = (round(self.rng.uniform(-0.2, 0.5), 2), round(self.rng.uniform(-0.5, 0.5), 2))
            linear, angular = command
            left, right = self._coils_out(ahead=linear * TICK_S) if linear >= 0 else (False, False)
            if left or right or not self._stays_inside(linear):
                # The mower refuses to cross the wire and turns back in, whatever it is told.
                yield self._step(
                    0.0,
                    self._towards_centre(),
                    "remote control",
                    "perimeter detected",
                    left=left,
                    right=right,
                    cmd=command,
                )
                continue
            yield self._step(linear, angular, "remote control", "manual driving", cmd=command)
        yield self._step(0.0, 0.0, "remote control", "idle", cmd=(0.0, 0.0))

    def _return_to_dock(self) -> Iterator[Emission]:
        yield from self._goto((0.6, self.y), "returning to dock", "driving straight")
        yield self._step(0.0, 0.0, "returning to dock", "perimeter detected", left=False, right=True)
        yield from self._goto((DOCK[0], DOCK[1] + 0.6), "returning to dock", "following border wire")
        yield from self._goto(DOCK, "docking", "driving straight")
        self.yaw = -math.pi / 2

    # -- motion primitives

    def _turn(self, angle: float, state: str) -> Iterator[Emission]:
        steps = max(1, math.ceil(abs(angle) / (TURN_RATE * TICK_S)))
        for _ in range(steps):
            yield self._step(0.0, angle / (steps * TICK_S), state, "turning")

    def _straight(self, distance: float, state: str, substate: str) -> Iterator[Emission]:
        steps = max(1, math.ceil(distance / (MOW_SPEED * TICK_S)))
        for _ in range(steps):
            yield self._step(distance / (steps * TICK_S), 0.0, state, substate)

    def _goto(self, target: tuple[float, float], state: str, substate: str) -> Iterator[Emission]:
        dx, dy = target[0] - self.x, target[1] - self.y
        if math.hypot(dx, dy) < 0.05:
            return
        turn = _wrap(math.atan2(dy, dx) - self.yaw)
        if abs(turn) > 0.05:
            yield from self._turn(turn, state)
        yield from self._straight(math.hypot(dx, dy), state, substate)

    def _step(
        self,
        linear: float,
        angular: float,
        state: str,
        substate: str,
        *,
        left: bool = False,
        right: bool = False,
        cmd: tuple[float, float] | None = None,
    ) -> Emission:
        """Advance one tick of unicycle motion and publish every topic."""
        self.yaw = _wrap(self.yaw + angular * TICK_S)
        self.x += linear * math.cos(self.yaw) * TICK_S
        self.y += linear * math.sin(self.yaw) * TICK_S
        self.t += timedelta(seconds=TICK_S)
        self._publish(linear, angular, state, substate, left, right, cmd)
        return Emission(self.t, self.entity.snapshot(self.t))

    def _publish(self, linear, angular, state, substate, left, right, cmd) -> None:
        t, rng, e = self.t, self.rng, self.entity
        measured_v = linear + rng.gauss(0.0, 0.005) if linear else 0.0
        measured_w = angular + rng.gauss(0.0, 0.005) if angular else 0.0
        e.set("odom", "Object", ros.odometry(t, self.x, self.y, self.yaw, measured_v, measured_w), t)
        lat, lon = sites.offset(sites.GARDEN_ORIGIN, self.x + rng.gauss(0, 0.3), self.y + rng.gauss(0, 0.3))
        e.set("location", "geo:json", sites.geo_point(lat, lon), t)
        e.set("navigationState", "Object", ros.scalar(code(STATE, state)), t)
        e.set("navigationSubState", "Object", ros.scalar(code(SUBSTATE, substate)), t)
        e.set("perimeterLeft", "Object", ros.scalar(left), t)
        e.set("perimeterRight", "Object", ros.scalar(right), t)
        sonar = ros.range_reading(
            t,
            self._obstacle_distance() + rng.gauss(0.0, 0.01),
            frame_id="sonar_front",
            radiation_type=ros.ULTRASOUND,
            fov=0.5,
            min_range=0.02,
            max_range=SONAR_MAX,
        )
        e.set("obstacleDistance", "Object", sonar, t)
        if cmd is not None:
            e.set("cmd_vel", "Object", ros.twist(*cmd), t)

    # -- sensing

    def _coils_out(self, ahead: float = MOW_SPEED * TICK_S) -> tuple[bool, bool]:
        """Whether the left / right perimeter coil would be past the wire after ``ahead`` metres."""
        fx, fy = math.cos(self.yaw), math.sin(self.yaw)
        reach = COIL_AHEAD + max(ahead, 0.0)
        cx, cy = self.x + reach * fx, self.y + reach * fy
        left = (cx - COIL_SIDE * fy, cy + COIL_SIDE * fx)
        right = (cx + COIL_SIDE * fy, cy - COIL_SIDE * fx)
        return not _in_garden(*left), not _in_garden(*right)

    def _stays_inside(self, linear: float, margin: float = 0.3) -> bool:
        """Whether one tick at ``linear`` keeps the mower's centre ``margin`` inside the wire."""
        x = self.x + linear * math.cos(self.yaw) * TICK_S
        y = self.y + linear * math.sin(self.yaw) * TICK_S
        return margin <= x <= sites.GARDEN_WIDTH_M - margin and margin <= y <= sites.GARDEN_DEPTH_M - margin

    def _maybe_place_obstacle(self) -> None:
        """A toy or a hedgehog somewhere on a quarter of the lanes."""
        self.obstacle = None
        if self.rng.random() < 0.25:
            along = self.rng.uniform(2.0, sites.GARDEN_WIDTH_M - 3.0)
            x = along if math.cos(self.yaw) > 0 else sites.GARDEN_WIDTH_M - along
            self.obstacle = (x, self.y)

    def _obstacle_distance(self) -> float:
        """Range to the obstacle if it is in front of the sonar, else the sonar's maximum."""
        if self.obstacle is None:
            return SONAR_MAX
        dx, dy = self.obstacle[0] - self.x, self.obstacle[1] - self.y
        along = dx * math.cos(self.yaw) + dy * math.sin(self.yaw)
        if along <= 0 or abs(-dx * math.sin(self.yaw) + dy * math.cos(self.yaw)) > 0.4:
            return SONAR_MAX
        return min(along, SONAR_MAX)

    def _towards_centre(self) -> float:
        """A yaw rate that turns the mower towards the middle of the garden."""
        centre = (sites.GARDEN_WIDTH_M / 2, sites.GARDEN_DEPTH_M / 2)
        turn = _wrap(math.atan2(centre[1] - self.y, centre[0] - self.x) - self.yaw)
        return max(-TURN_RATE, min(TURN_RATE, turn))


def _in_garden(x: float, y: float) -> bool:
    return 0.0 <= x <= sites.GARDEN_WIDTH_M and 0.0 <= y <= sites.GARDEN_DEPTH_M


def _wrap(angle: float) -> float:
    return math.atan2(math.sin(angle), math.cos(angle))
