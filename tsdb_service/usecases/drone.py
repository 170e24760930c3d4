"""eProsima drone: missions from home to one of 8 remote sensors, and back.

Each mission picks a sensor at random with the joint use case's priorities,
takes off, flies there on a noisy path (the cross-track error is a mean-
reverting random walk, and the GNSS fix adds metre-level noise), hovers to
read the sensor's temperature and humidity, flies home and lands.

Entities:

* ``urn:ngsiv2:ROS2System:Drone01``: ``location`` (geo:json Point mapped from
  sensor_msgs/NavSatFix), ``altitude`` (std_msgs/Float32, metres above home),
  ``missionState`` (std_msgs/UInt8, see enums), ``missionTarget``
  (std_msgs/UInt8: the sensor number 1-8, 0 when none) and ``battery``
  (std_msgs/Float32, percent);
* ``urn:ngsiv2:RemoteSensor:Sensor01`` .. ``08``: ``location`` (geo:json),
  ``priority``, ``temperature`` and ``humidity`` (Number). A sensor is
  notified once at installation (with a first reading, so every query has
  data from the start) and once per visit: its temperature samples are its
  visits plus one.
"""

from __future__ import annotations

import math
import random
from collections.abc import Iterator
from datetime import datetime, timedelta

from tsdb_service.usecases import ros, sites
from tsdb_service.usecases.base import Emission, Simulator
from tsdb_service.usecases.enums import DRONE_MISSION_STATE, code
from tsdb_service.usecases.orion import EntityState

CRUISE_SPEED = 15.0  # m/s
CRUISE_ALTITUDE = 40.0  # m
CLIMB_S = 8.0
READ_S = 20.0
SETTLE_S = 2.0  # from arrival over a sensor to the start of its reading
FLIGHT_EVERY_S = 5.0  # position updates while flying
GNSS_SIGMA_M = 1.5
CROSS_TRACK_SIGMA_M = 4.0


class Drone(Simulator):
    name = "drone"
    title = "eProsima drone"
    tenancy = sites.DRONE
    subjects = (("^urn:ngsiv2:ROS2System:Drone", "ROS2System"), (".*", sites.SENSOR_TYPE))

    def emissions(self, start: datetime, rng: random.Random) -> Iterator[Emission]:
        return _Flight(start, rng).run()


def choose_sensor(rng: random.Random) -> int:
    """Index (0-7) of the next mission's sensor, drawn with the mission priorities."""
    return rng.choices(range(len(sites.SENSORS)), weights=sites.MISSION_PRIORITIES)[0]


class _Flight:
    def __init__(self, start: datetime, rng: random.Random):
        self.t, self.rng = start, rng
        self.position = sites.DRONE_HOME
        self.altitude, self.battery = 0.0, 100.0
        self.drone = EntityState(sites.DRONE_ID, "ROS2System")
        self.sensors = [EntityState(sensor_id, sites.SENSOR_TYPE) for sensor_id in sites.SENSOR_IDS]

    def run(self) -> Iterator[Emission]:
        yield from self._provision_sensors()
        while True:
            yield from self._mission(choose_sensor(self.rng))

    def _provision_sensors(self) -> Iterator[Emission]:
        """Installation: each sensor's place, priority and a first reading taken on site."""
        for number, (entity, (_, (lat, lon), priority)) in enumerate(zip(self.sensors, sites.SENSORS, strict=True)):
            temperature, humidity = self._measure(number)
            entity.set("location", "geo:json", sites.geo_point(lat, lon), self.t)
            entity.set("priority", "Number", priority, self.t)
            entity.set("temperature", "Number", temperature, self.t)
            entity.set("humidity", "Number", humidity, self.t)
            yield Emission(self.t, entity.snapshot(self.t))

    def _mission(self, target: int) -> Iterator[Emission]:
        where = sites.SENSORS[target][1]
        yield from self._idle(self.rng.uniform(5.0, 15.0))
        yield from self._climb(CRUISE_ALTITUDE, "taking off", target)
        yield from self._fly(where, "flying to sensor", target)
        yield from self._read(target)
        yield from self._fly(sites.DRONE_HOME, "returning home", target)
        yield from self._climb(0.0, "landing", target)
        self.battery = min(100.0, self.battery + 10.0)  # a quick swap at home

    # -- phases

    def _idle(self, seconds: float) -> Iterator[Emission]:
        self._advance(seconds)
        yield self._report("landed at home", None)

    def _climb(self, altitude: float, state: str, target: int) -> Iterator[Emission]:
        start_altitude, steps = self.altitude, 4
        for step in range(1, steps + 1):
            self._advance(CLIMB_S / steps)
            self.altitude = start_altitude + (altitude - start_altitude) * step / steps
            yield self._report(state, target)

    def _fly(self, goal: tuple[float, float], state: str, target: int) -> Iterator[Emission]:
        """Straight to ``goal`` with a wandering cross-track error that dies out on arrival."""
        origin = self.position
        length = sites.distance_m(origin, goal)
        course = sites.bearing_deg(origin, goal)
        steps = max(1, math.ceil(length / (CRUISE_SPEED * FLIGHT_EVERY_S)))
        cross = 0.0
        for step in range(1, steps + 1):
            self._advance(length / steps / CRUISE_SPEED)
            cross = 0.7 * cross + self.rng.gauss(0.0, CROSS_TRACK_SIGMA_M)
            along = length * step / steps
            offset = cross if step < steps else 0.0
            lon, lat, _ = sites.WGS84.fwd(origin[1], origin[0], course, along)
            lon, lat, _ = sites.WGS84.fwd(lon, lat, course + 90.0, offset) if offset else (lon, lat, 0)
            self.position = (lat, lon)
            yield self._report(state, target)
        self.position = goal

    def _read(self, target: int) -> Iterator[Emission]:
        """Hover over the sensor and read it. The arrival was reported by the
        flight's last step; the hover starts a moment later, so each instant
        of the drone has exactly one state, position and altitude."""
        self._advance(SETTLE_S)
        yield self._report("reading sensor", target)
        self._advance(READ_S)
        sensor = self.sensors[target]
        temperature, humidity = self._measure(target)
        sensor.set("temperature", "Number", temperature, self.t)
        sensor.set("humidity", "Number", humidity, self.t)
        yield Emission(self.t, sensor.snapshot(self.t))
        yield self._report("reading sensor", target)

    # -- state

    def _advance(self, seconds: float) -> None:
        self.t += timedelta(seconds=seconds)
        if self.altitude > 0:
            self.battery = max(5.0, self.battery - seconds * 0.02)

    def _measure(self, target: int) -> tuple[float, float]:
        """A daily temperature cycle (warmest mid-afternoon) with per-sensor offsets and noise."""
        hour = self.t.hour + self.t.minute / 60
        daily = math.cos((hour - 15.0) / 24.0 * 2 * math.pi)
        temperature = 18.0 + 7.0 * daily + 0.4 * (target - 3.5) + self.rng.gauss(0.0, 0.3)
        humidity = 55.0 - 15.0 * daily - 0.8 * (target - 3.5) + self.rng.gauss(0.0, 1.0)
        return round(temperature, 2), round(min(100.0, max(0.0, humidity)), 1)

    def _report(self, state: str, target: int | None) -> Emission:
        t, d, rng = self.t, self.drone, self.rng
        east, north = rng.gauss(0.0, GNSS_SIGMA_M), rng.gauss(0.0, GNSS_SIGMA_M)
        lat, lon = sites.offset(self.position, east, north)
        d.set("location", "geo:json", sites.geo_point(lat, lon), t)
        d.set("altitude", "Object", ros.scalar(self.altitude + rng.gauss(0.0, 0.2) if self.altitude else 0.0), t)
        d.set("missionState", "Object", ros.scalar(code(DRONE_MISSION_STATE, state)), t)
        d.set("missionTarget", "Object", ros.scalar(0 if target is None else target + 1), t)
        d.set("battery", "Object", ros.scalar(self.battery), t)
        return Emission(t, d.snapshot(t))
