"""``replay``: stored history sent again, in time order, at real speed or a factor of it.

Pacing: the first update goes out at once; every later one when as much
wall time has passed since as history time passed between them, divided
by ``speed`` (``None``: as fast as the target takes them). A target slower
than the pace is never skipped ahead of: each update waits for the one
before, and the report says how late they went out (``lateness``). The
updates of one instant for one tenant and service path go out together
(one request, one MQTT message).

Invariants:

* **Never into the tenant it reads from** unless ``force``: the check
  happens before anything is sent (``check_tenants``).
* Every update carries the marker (``targets.MARKER``) naming this replay,
  its source and the sample's original time.
* Memory is the source's (a batch and a sort window) plus one instant's
  updates, whatever the span replayed.
* A stop (``stop`` set, e.g. at Ctrl-C) ends after the update being sent;
  the report says up to which time history was sent.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from datetime import UTC, datetime

from tsdb_service.commands.replay.source import Update
from tsdb_service.commands.replay.targets import Marker, Outgoing, Target


class ReplayRefused(ValueError):
    """The replay cannot run as asked; one line."""


@dataclass
class ReplayReport:
    target: str
    updates: int = 0
    samples: int = 0
    sends: int = 0
    first: datetime | None = None  # the first and last update's original time
    last: datetime | None = None
    seconds: float = 0.0  # wall time from the first send to the end of the last
    lateness: list[float] = field(default_factory=list)  # per send: seconds after its due time (pacing only)
    stopped: bool = False

    @property
    def late_max(self) -> float:
        return max(self.lateness, default=0.0)

    @property
    def late_mean(self) -> float:
        return sum(self.lateness) / len(self.lateness) if self.lateness else 0.0


def check_tenants(source_tenant: str, target_tenant: str, force: bool) -> None:
    """``ReplayRefused`` when the replay would write into the tenant it reads from."""
    if source_tenant == target_tenant and not force:
        shown = source_tenant or "the default tenant"
        raise ReplayRefused(
            f"the replay would send into the tenant it reads from ({shown}): give --to-service OTHER "
            "(a staging tenant), or --force to relive it there (every update carries the tsdbReplay marker)"
        )


def replay(
    updates: Iterable[Update],
    target: Target,
    marker: Marker,
    *,
    tenant: str,
    service_path: str | None = None,
    speed: float | None = 1.0,
    retime: bool = False,
    stop: threading.Event | None = None,
    progress: Callable[[ReplayReport], None] | None = None,
    clock: Callable[[], float] = time.monotonic,
    sleep: Callable[[float], None] = time.sleep,
) -> ReplayReport:
    """Send ``updates`` (time order) to ``target`` under ``tenant`` (and
    ``service_path``, else each update's own), paced by ``speed``."""
    report = ReplayReport(target.name)
    started = t0 = None
    for batch in _instants(updates, tenant, service_path):
        original = batch.updates[0].time
        if t0 is None:
            t0, started = original, clock()
        assert started is not None
        due = started + (original - t0).total_seconds() / speed if speed else None
        if due is not None:
            wait = due - clock()
            if wait > 0:
                stop.wait(wait) if stop is not None else sleep(wait)  # a stop ends the wait at once
            report.lateness.append(max(0.0, clock() - due))
        if stop is not None and stop.is_set():
            report.stopped = True
            break
        sent_as = datetime.now(UTC) if retime else original
        target.send(Outgoing(batch.tenant, batch.service_path, batch.updates, sent_as), marker)
        report.sends += 1
        report.updates += len(batch.updates)
        report.samples += sum(len(u.attrs) for u in batch.updates)
        report.first = report.first or original
        report.last = original
        if progress is not None:
            progress(report)
    if started is not None:
        report.seconds = clock() - started
    return report


def _instants(updates: Iterable[Update], tenant: str, service_path: str | None) -> Iterator[Outgoing]:
    """Consecutive updates of one instant and (target) service path, together."""
    group: list[Update] = []
    path = ""
    for update in updates:
        this = service_path or update.service_path
        if group and (update.time != group[0].time or this != path):
            yield Outgoing(tenant, path, group, group[0].time)
            group = []
        path = this
        group.append(update)
    if group:
        yield Outgoing(tenant, path, group, group[0].time)
