"""Feed a served process with the demo's simulators, on virtual time.

``feed_phases`` runs each phase (a simulator's ``(speedup, wall seconds)``)
through the demo's runner (``tsdb_service.demo.runner.run``) on a
``VirtualTime`` clock of its own: exactly the notifications of a wall-clock
run, as fast as the service acknowledges them. Every phase's simulated span
ends at ``end`` (a run that has just finished), the phases run at once.
"""

from __future__ import annotations

import asyncio
from collections.abc import Mapping
from datetime import datetime, timedelta

from tsdb_service.demo.runner import RunConfig, Stats, VirtualTime, run
from tsdb_service.usecases.registry import SIMULATORS


async def feed_phases(
    url: str, phases: Mapping[str, tuple[float, float]], *, seed: int, end: datetime, concurrency: int = 16
) -> dict[str, Stats]:
    """Each simulator's stats (sent, acknowledged, failed) once every phase is done."""
    runs = [
        run(
            [SIMULATORS[name]],
            RunConfig(
                url,
                speedup=speedup,
                duration=seconds,
                seed=seed,
                concurrency=concurrency,
                start=end - timedelta(seconds=speedup * seconds),
            ),
            timer=VirtualTime(),
        )
        for name, (speedup, seconds) in phases.items()
    ]
    stats: dict[str, Stats] = {}
    for result in await asyncio.gather(*runs):
        stats.update(result)
    return stats
