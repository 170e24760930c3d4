"""What every use-case simulator is: a deterministic stream of entity updates.

A simulator knows nothing about HTTP or wall-clock time. It yields
``Emission``s (an entity snapshot at a simulated instant) in time order, from
a seeded ``random.Random``; the runner paces them and turns them into Orion
notifications. Keeping the physics pure makes it testable without a server
and makes ``--seed`` reproduce a run exactly.
"""

from __future__ import annotations

import random
from abc import ABC, abstractmethod
from collections.abc import Iterator
from dataclasses import dataclass
from datetime import datetime

from tsdb_service.usecases.sites import Tenancy


@dataclass(frozen=True, slots=True)
class Emission:
    """One entity, as Orion would notify it after an update at simulated time ``at``."""

    at: datetime
    entity: dict


class Simulator(ABC):
    """A use case: its tenancy, the entities a subscription must select, its physics."""

    name: str  # CLI name and notifications/ folder: "lawnmower"
    title: str  # for people: "Bosch lawnmower"
    tenancy: Tenancy
    # (idPattern, type) pairs: what the Orion subscription selects.
    subjects: tuple[tuple[str, str], ...]

    @abstractmethod
    def emissions(self, start: datetime, rng: random.Random) -> Iterator[Emission]:
        """Endless, time-ordered updates starting at ``start``; the caller stops pulling."""
