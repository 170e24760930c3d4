"""The three use cases by name: the one list the CLI, the runner and the files use."""

from __future__ import annotations

from collections.abc import Iterable

from tsdb_service.usecases.base import Simulator
from tsdb_service.usecases.drone import Drone
from tsdb_service.usecases.lawnmower import Lawnmower
from tsdb_service.usecases.warehouse import Warehouse

SIMULATORS: dict[str, Simulator] = {sim.name: sim for sim in (Lawnmower(), Warehouse(), Drone())}


def select(names: Iterable[str] | None) -> list[Simulator]:
    """Simulators by name (comma lists allowed), all of them when none are given."""
    wanted = [part.strip() for name in (names or []) for part in name.split(",") if part.strip()]
    unknown = sorted(set(wanted) - SIMULATORS.keys())
    if unknown:
        raise ValueError(f"unknown use case {', '.join(unknown)}: choose from {', '.join(SIMULATORS)}")
    return [SIMULATORS[name] for name in wanted] if wanted else list(SIMULATORS.values())
