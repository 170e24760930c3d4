"""The integer enumerations the use-case robots publish, with their names.

The ROS topics carry bare integers (``{"data": 3}``); people need names. This
module is the single place both sides agree on: the simulators publish these
codes, and the dashboards import the same dicts for their value mappings, so
a renamed state cannot silently disagree between them.

Plain ``dict[int, str]`` on purpose: trivially importable, JSON-friendly, and
ordered by code.
"""

from __future__ import annotations

# -- Bosch lawnmower -----------------------------------------------------------

# navigationState (std_msgs/UInt8): what the mower is doing overall.
LAWNMOWER_NAVIGATION_STATE: dict[int, str] = {
    0: "docked",
    1: "leaving dock",
    2: "mowing",
    3: "returning to dock",
    4: "docking",
    5: "remote control",
    6: "error",
}

# navigationSubState (std_msgs/UInt8): the manoeuvre inside that state.
LAWNMOWER_NAVIGATION_SUBSTATE: dict[int, str] = {
    0: "idle",
    1: "charging",
    2: "driving straight",
    3: "turning",
    4: "perimeter detected",
    5: "avoiding obstacle",
    6: "following border wire",
    7: "manual driving",
}

# -- PIAP smart warehouse --------------------------------------------------------

# doorState (std_msgs/UInt8): where the automated door is.
DOOR_STATE: dict[int, str] = {
    0: "closed",
    1: "open",
    2: "in motion",
}

# doorCommand (std_msgs/UInt8): the command the door controller is executing.
DOOR_COMMAND: dict[int, str] = {
    0: "idle",
    1: "open",
    2: "close",
    3: "stop",
}

# warningLight (std_msgs/UInt8): the light next to the door.
WARNING_LIGHT_STATE: dict[int, str] = {
    0: "off",
    1: "on",
}

# warningLightCommand (std_msgs/UInt8): what the controller asks of the light.
WARNING_LIGHT_COMMAND: dict[int, str] = {
    0: "off",
    1: "on",
}

# -- eProsima drone ----------------------------------------------------------------

# missionState (std_msgs/UInt8): the phase of the current mission.
DRONE_MISSION_STATE: dict[int, str] = {
    0: "landed at home",
    1: "taking off",
    2: "flying to sensor",
    3: "reading sensor",
    4: "returning home",
    5: "landing",
}

# Every enumeration by the attribute that carries it, per use case: what the
# dashboards' value mappings and the demo tests iterate over.
ENUMERATIONS: dict[str, dict[str, dict[int, str]]] = {
    "lawnmower": {
        "navigationState": LAWNMOWER_NAVIGATION_STATE,
        "navigationSubState": LAWNMOWER_NAVIGATION_SUBSTATE,
    },
    "warehouse": {
        "doorState": DOOR_STATE,
        "doorCommand": DOOR_COMMAND,
        "warningLight": WARNING_LIGHT_STATE,
        "warningLightCommand": WARNING_LIGHT_COMMAND,
    },
    "drone": {
        "missionState": DRONE_MISSION_STATE,
    },
}


def code(enumeration: dict[int, str], name: str) -> int:
    """The integer for a state name, so simulators read as prose, not magic numbers."""
    for value, label in enumeration.items():
        if label == name:
            return value
    raise KeyError(f"{name!r} is not one of {sorted(enumeration.values())}")
