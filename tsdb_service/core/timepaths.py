"""``TSDB_TIME_INDEX_PATHS``: attributes whose samples are timed by a stamp inside their value.

A robot's message carries the time it was measured (ROS ``header.stamp``:
``{"sec", "nanosec"}``); the ROS 2 IoT Agent forwards the message as the
attribute's value, and the broker's ``TimeInstant`` is when the agent
passed it on. A rule names the attribute and the value path of its stamp::

    odom=header.stamp                       # the attribute odom, any entity type
    Lawnmower/odom=header.stamp             # only in entities of type Lawnmower
    odom=header.stamp,Drone/fix=header.stamp

Rules are separated by ``,``; a selector is ``ATTR`` or ``TYPE/ATTR``
(split at the last ``/``: a type may contain ``/``, an attribute named
here may not), ``*/ATTR`` is ``ATTR``; the path is ``core.valuesteps``'
grammar. A type's own rule for an attribute wins over the any-type one.
What the parser does with them: ``parse.timeindex``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache

from tsdb_service.core.valuesteps import Steps, parse_steps, steps_text

ANY_TYPE = "*"
_NOT_IN_NAMES = set("=(),")


@dataclass(frozen=True, slots=True)
class TimePaths:
    """The rules, by attribute name then entity type (``ANY_TYPE`` for all)."""

    rules: dict[str, dict[str, Steps]] = field(default_factory=dict)

    def __bool__(self) -> bool:
        return bool(self.rules)

    @property
    def attributes(self) -> frozenset[str]:
        return frozenset(self.rules)

    def steps(self, entity_type: str, attr: str) -> Steps | None:
        """The stamp's path in ``attr`` of an entity of ``entity_type``, or None."""
        by_type = self.rules.get(attr)
        if by_type is None:
            return None
        found = by_type.get(entity_type)
        return found if found is not None else by_type.get(ANY_TYPE)

    def text(self) -> str:
        """The rules as the setting writes them (sorted)."""
        return ",".join(
            f"{attr if etype == ANY_TYPE else f'{etype}/{attr}'}={steps_text(steps)}"
            for attr, by_type in sorted(self.rules.items())
            for etype, steps in sorted(by_type.items())
        )


NO_TIME_PATHS = TimePaths()


@lru_cache(maxsize=16)
def parse_time_paths(spec: str) -> TimePaths:
    """The rules of ``spec``; ``ValueError`` (one line, naming the rule) otherwise."""
    rules: dict[str, dict[str, Steps]] = {}
    for number, item in enumerate(spec.split(","), 1):
        rule = item.strip()
        if not rule:
            continue
        selector, eq, path = rule.partition("=")
        where = f"TSDB_TIME_INDEX_PATHS rule {number} ({rule[:80]!r})"
        if not eq or not path.strip():
            raise ValueError(f"{where}: expected [TYPE/]ATTR=PATH, e.g. odom=header.stamp")
        etype, slash, attr = selector.strip().rpartition("/")
        etype, attr = (etype.strip() or ANY_TYPE) if slash else ANY_TYPE, attr.strip()
        if not attr or _NOT_IN_NAMES & set(attr) or any(c.isspace() for c in attr):
            raise ValueError(f"{where}: {attr[:60]!r} is not an attribute name")
        try:
            steps = parse_steps(path.strip())
        except ValueError as exc:
            raise ValueError(f"{where}: {exc}") from None
        by_type = rules.setdefault(attr, {})
        if etype in by_type:
            raise ValueError(f"{where}: a second rule for the same attribute and type")
        by_type[etype] = steps
    return TimePaths(rules)
