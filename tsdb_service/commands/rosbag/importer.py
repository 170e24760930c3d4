"""``import_rosbag``: a robot's recording into history, as if its messages had been notified.

Each message becomes the ``EntitySample`` the ROS 2 IoT Agent and Orion
would have made of it (``mapping``: which entity and attributes), timed by
its ``header.stamp`` (else the bag's receive time), and goes through the
write seam (``AppendSamples``) as ``/v2/notify`` writes: the ingest log,
rollups, the rejected store and retention see it like any notification.

Invariants:

* **Nothing half-imported that a resume cannot finish.** The whole
  selection is read once before anything is written (``Recording.check``):
  a damaged or truncated bag, a map naming missing fields or a type
  without a definition is one error line and nothing stored.
* **Never twice.** The import is identified by the recording's content and
  the plan (``Recording.check``'s digest and ``Plan.canonical``). Its
  progress, how many messages of the one order (``bag.ordered``) are
  stored, is recorded as a delivery (``write.ops.Delivery``, client id
  ``rosbag:<identity>``) **in the transaction of each batch's samples**: a
  crash leaves both or neither. A resume skips exactly that many; the same
  bag imported again finds it complete and stores nothing (``again`` starts
  a new round on purpose, e.g. after deleting what the first one stored).
* **Totals are checked**: the samples of the series the plan writes must
  grow by exactly what this run wrote (another writer adding to those
  series meanwhile fails the check: import a recording into entities of
  its own).
* A message whose bytes do not fit its type is kept in the rejected store
  (``RecordRejected``, its raw bytes) and the import goes on: one bad
  message never blocks the ones behind it. Rejections are written just
  before their batch's samples: after a crash between the two a resume
  keeps one twice, never none.
"""

from __future__ import annotations

import hashlib
import math
import sys
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any

import orjson

from tsdb_service.commands.inorder import InOrder
from tsdb_service.commands.rosbag.bag import BagError, MessageUnreadable, RawMessage, Recording
from tsdb_service.commands.rosbag.mapping import EXPORTED, GEO_JSON, Plan, TopicPlan, plan
from tsdb_service.core.model import AttrSample, EntitySample, RejectedNotification
from tsdb_service.core.query import EntityFilter, Scope, TimeRange
from tsdb_service.core.valuesteps import extract
from tsdb_service.parse.timeindex import read_stamp
from tsdb_service.parse.values import TooDeep, attr_sample
from tsdb_service.read.requests import SamplesIn, SeriesSelect
from tsdb_service.storage.store import Store
from tsdb_service.write.ops import AppendSamples, Delivery, RecordRejected

BATCH_SAMPLES = 50_000
PROGRESS_EVERY_S = 0.5
CLIENT_PREFIX = "rosbag:"
SHOWN_PROBLEMS = 5
_EPOCH = datetime(1970, 1, 1, tzinfo=UTC)
UNREADABLE = "BagMessageUnreadable"  # the rejected store's error for a message we could not decode


class ImportNotVerified(RuntimeError):
    """The import ran, but the target's totals are not what they must be."""


@dataclass
class TopicReport:
    messages: int = 0  # this run's
    samples: int = 0
    unstamped: int = 0  # stamp path given, no readable stamp there: stored at the receive time
    rejected: int = 0


@dataclass
class RosbagReport:
    bag: str
    kind: str
    plan: Plan
    total: int = 0  # messages the plan imports
    already: int = 0  # stored by earlier runs of this import
    complete_before: bool = False  # the same import was complete: nothing done
    topics: dict[str, TopicReport] = field(default_factory=dict)
    problems: list[str] = field(default_factory=list)
    totals: dict[tuple[str, str], int] = field(default_factory=dict)  # (tenant, type) → samples of the plan's series
    seconds: float = 0.0

    @property
    def messages(self) -> int:
        return sum(t.messages for t in self.topics.values())

    @property
    def samples(self) -> int:
        return sum(t.samples for t in self.topics.values())

    @property
    def rejected(self) -> int:
        return sum(t.rejected for t in self.topics.values())

    @property
    def unstamped(self) -> int:
        return sum(t.unstamped for t in self.topics.values())


def import_rosbag(
    path: str | Path,
    target: Store | None,
    *,
    spec: dict | None = None,
    source: str = "the map",
    defaults: dict | None = None,
    again: bool = False,
    dry_run: bool = False,
    progress: bool = False,
    batch_samples: int = BATCH_SAMPLES,
) -> RosbagReport:
    """Import the recording at ``path`` into ``target`` (None only with
    ``dry_run``) as the map ``spec`` says; the report, verified. ``BagError``
    and ``mapping.MapError`` (one line each) before anything is written."""
    with PreparedImport.open(path, spec, source, defaults) as prepared:
        if dry_run or target is None:
            if not dry_run:
                raise ValueError("a target store is needed unless dry_run")
            return prepared.report
        return prepared.run(target, again=again, progress=progress, batch_samples=batch_samples)


class PreparedImport:
    """A recording opened, planned and checked: nothing can fail any more
    because of the bag or the map, and nothing is written yet. ``run`` writes."""

    def __init__(self, recording: Recording, chosen: Plan, digest: bytes, report: RosbagReport):
        self.recording, self.plan, self.digest, self.report = recording, chosen, digest, report
        self.started = time.monotonic()

    @classmethod
    def open(
        cls, path: str | Path, spec: dict | None = None, source: str = "the map", defaults: dict | None = None
    ) -> PreparedImport:
        started = time.monotonic()
        recording = Recording.open(path)
        try:
            chosen = plan(recording, spec or {}, source, defaults)
            report = RosbagReport(str(path), recording.kind, chosen)
            report.topics = {name: TopicReport() for name in chosen.topics}
            checked = recording.check(set(chosen.topics))
        except BaseException:
            recording.close()
            raise
        report.total = checked.total
        prepared = cls(recording, chosen, checked.digest, report)
        prepared.started = started
        return prepared

    def __enter__(self) -> PreparedImport:
        return self

    def __exit__(self, *exc_info) -> None:
        self.recording.close()

    def run(
        self, target: Store, *, again: bool = False, progress: bool = False, batch_samples: int = BATCH_SAMPLES
    ) -> RosbagReport:
        """Write what is not stored yet, check the totals; the report."""
        if self.report.total:
            identity = hashlib.blake2b(self.digest + self.plan.canonical(), digest_size=16)
            job = _Job(self.recording, self.plan, target, CLIENT_PREFIX + identity.hexdigest(), identity.digest())
            job.report, job.progress, job.batch_samples = self.report, progress, batch_samples
            job.run(again)
        self.report.seconds = time.monotonic() - self.started
        return self.report


class _Job:
    """One run: where the import stands, the messages after it, the check."""

    def __init__(self, recording: Recording, chosen: Plan, target: Store, client_id: str, digest: bytes):
        self.recording, self.plan, self.target = recording, chosen, target
        self.report = RosbagReport("", "", chosen)
        self.client_id, self.digest = client_id, digest
        self.progress, self.batch_samples = False, BATCH_SAMPLES
        self.batch: list[EntitySample] = []
        self.rejected: list[RecordRejected] = []
        self.batch_n = 0
        self.done = 0  # messages of the order stored (this run's and earlier ones')
        self.recorded = 0  # what the last batch's progress says
        self.round = 0
        self.writes = InOrder(self._write, "rosbag-import")
        self.started = time.monotonic()
        self.shown = 0.0
        self.exported = {name for name, topic in recording.topics.items() if EXPORTED["attribute"] in topic.metadata}

    def run(self, again: bool) -> None:
        total = self.report.total
        self.target.sync()
        stored = self.target.deliveries(self.client_id, 1)
        seq = stored[0][0] if stored else 0
        self.round, self.done = divmod(seq, total)
        if seq and not self.done:  # the last round is complete
            if not again:
                self.report.complete_before = True
                self.report.already = total
                return
            self.done = 0  # a new round: ``round`` counts the ones complete
        self.report.already = self.recorded = self.done
        before = self._counts()
        try:
            for message in self._after(self.done):
                self._message(message)
            self._flush(last=True)
        finally:
            self.writes.close()  # a batch in flight (e.g. at Ctrl-C) ends committed or not, never half
        if self.progress:
            self._show(final=True)
            print(file=sys.stderr)
        self._verify(before)

    def _after(self, skip: int) -> Iterator[RawMessage]:
        for n, message in enumerate(self.recording.messages(set(self.plan.topics))):
            if n >= skip:
                yield message

    def _message(self, message: RawMessage) -> None:
        topic_plan = self.plan.topics[message.topic]
        counts = self.report.topics[message.topic]
        counts.messages += 1
        try:
            value = self.recording.decode(message)
            exported = message.topic in self.exported
            entity = _entity(topic_plan, value, message.time_ns, counts, exported, message.ngsi_type)
        except (MessageUnreadable, TooDeep) as exc:
            counts.rejected += 1
            self.rejected.append(RecordRejected(_rejection(topic_plan, message, exc, self.report.bag)))
            if len(self.report.problems) < SHOWN_PROBLEMS:
                self.report.problems.append(f"{message.topic} at {_iso(message.time_ns)}: {_words(exc)}")
        else:
            self._add(entity)
            self.batch_n += len(entity.attrs)
            counts.samples += len(entity.attrs)
        self.done += 1
        if self.batch_n >= self.batch_samples:
            self._flush()

    def _add(self, entity: EntitySample) -> None:
        """Into the batch; messages of one entity at one instant (topics of a
        robot stamped together) share a row, as one notification's attributes do."""
        last = self.batch[-1] if self.batch else None
        if (
            last is not None
            and last.time_index == entity.time_index
            and (last.entity_id, last.entity_type, last.tenant, last.service_path)
            == (entity.entity_id, entity.entity_type, entity.tenant, entity.service_path)
            and not {a.name for a in last.attrs} & {a.name for a in entity.attrs}
        ):
            last.attrs.extend(entity.attrs)
        else:
            self.batch.append(entity)

    def _flush(self, last: bool = False) -> None:
        """Commit the batch, with the import's progress in its transaction, in
        the background while the next one is decoded (one at a time, in order)."""
        if self.done > self.recorded:
            seq = self.round * self.report.total + self.done
            progress = Delivery(self.client_id, seq, 0, self.digest, datetime.now(UTC), prune_below=seq)
            self.writes.submit([AppendSamples(self.batch, dedup=False, deliveries=(progress,)), *self.rejected])
            self.recorded = self.done
        self.batch, self.rejected, self.batch_n = [], [], 0
        if last:
            self.writes.wait()
        else:
            self._show()

    def _write(self, ops: Sequence) -> None:
        """The batch's rejected messages first, then its samples with the
        progress: a crash between the two can only keep a rejection twice
        (the resume decodes the batch again), never lose one."""
        rejected = [op for op in ops if isinstance(op, RecordRejected)]
        if rejected:
            self.target.write_sync(rejected)
        self.target.write_sync([op for op in ops if not isinstance(op, RecordRejected)])

    def _show(self, final: bool = False) -> None:
        now = time.monotonic()
        if not self.progress or (now < self.shown + PROGRESS_EVERY_S and not final):
            return
        self.shown = now
        elapsed = max(now - self.started, 1e-9)
        messages, samples = self.report.messages, self.report.samples
        pct = 100.0 * self.done / self.report.total
        print(
            f"\r[{'#' * int(pct // 4):<25}] {pct:5.1f}%  {self.done:,}/{self.report.total:,} messages  "
            f"{messages / elapsed:,.0f} messages/s  {samples / elapsed:,.0f} samples/s",
            end="",
            file=sys.stderr,
            flush=True,
        )

    # --- the check ------------------------------------------------------------------

    def _counts(self) -> dict[tuple[str, str], int]:
        """Samples stored in the plan's series, per (tenant, entity type)."""
        self.target.sync()
        querier = self.target.querier()
        wanted: dict[tuple[str, str], set[tuple]] = {}
        for topic_plan in self.plan.topics.values():
            for series in topic_plan.series():
                wanted.setdefault((series[0], series[3]), set()).add(series)
        out = {}
        for (tenant, etype), keys in sorted(wanted.items()):
            ids = tuple(sorted({key[2] for key in keys}))
            refs = querier.series(SeriesSelect(Scope(tenant), EntityFilter(ids=ids, types=(etype,))))
            sids = [r.sid for r in refs if (tenant, r.service_path, r.entity_id, r.entity_type, r.attr) in keys]
            out[tenant, etype] = querier.count(SamplesIn(sids, TimeRange())) if sids else 0
        return out

    def _verify(self, before: dict[tuple[str, str], int]) -> None:
        written: dict[tuple[str, str], int] = dict.fromkeys(before, 0)
        for name, topic_plan in self.plan.topics.items():
            written[topic_plan.tenant, topic_plan.entity_type] += self.report.topics[name].samples
        after = self._counts()
        self.report.totals = after
        wrong = {
            key: (before[key] + written[key], after[key]) for key in after if after[key] != before[key] + written[key]
        }
        if wrong:
            detail = ", ".join(
                f"{tenant or '(default)'}/{etype}: {want} samples expected, {got} found"
                for (tenant, etype), (want, got) in sorted(wrong.items())
            )
            raise ImportNotVerified(
                f"import NOT verified, the target's totals are wrong ({detail}); did another writer add to "
                "these entities meanwhile?"
            )


def _entity(
    plan_: TopicPlan, value: Any, time_ns: int, counts: TopicReport, exported: bool, own_type: str | None = None
) -> EntitySample:
    """One message as the entity sample the IoT Agent and Orion would have made
    (an exported MCAP message with its channel's own NGSI type, ``own_type``)."""
    moment = None
    if plan_.time is not None:
        moment = read_stamp(extract(value, plan_.time))
        if moment is None:
            counts.unstamped += 1
    at = moment or _EPOCH + timedelta(microseconds=time_ns // 1000)
    attrs: list[AttrSample] = []
    for f in plan_.fields:
        got = extract(value, f.steps) if f.steps else value
        ngsi_type = f.ngsi_type
        if exported:
            got, ngsi_type = _unwrapped(got), own_type or ngsi_type
        elif ngsi_type == GEO_JSON:
            got = _point(got)
        sample = attr_sample(f.name, ngsi_type, got, None)
        sample.observed_at = moment
        attrs.append(sample)
    return EntitySample(plan_.tenant, plan_.service_path, plan_.entity_id, plan_.entity_type, at, attrs)


def _point(fix: Any) -> Any:
    """A NavSatFix (anything with latitude and longitude) as a GeoJSON Point;
    no fix (NaN, missing) is a null value. A GeoJSON value is kept as it is."""
    if not isinstance(fix, dict) or "coordinates" in fix:
        return fix
    lat, lon, alt = fix.get("latitude"), fix.get("longitude"), fix.get("altitude")
    if not all(isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v) for v in (lat, lon)):
        return None
    coordinates = [lon, lat]
    if isinstance(alt, int | float) and not isinstance(alt, bool) and math.isfinite(alt):
        coordinates.append(alt)
    return {"type": "Point", "coordinates": coordinates}


def _unwrapped(message: Any) -> Any:
    """The stored value back from an exported message (``faces.export.mcap``):
    ``{"value": v}`` is ``v``; a position carries it in ``metadata``
    (``ngsi_value``), a geometry in ``ngsi_value``; an object is itself."""
    if not isinstance(message, dict):
        return message
    if len(message) == 1 and "value" in message:
        return message["value"]
    if "ngsi_value" in message:
        return orjson.loads(message["ngsi_value"])
    for item in message.get("metadata") or ():
        if isinstance(item, dict) and item.get("key") == "ngsi_value":
            return orjson.loads(item["value"])
    return message


def _rejection(plan_: TopicPlan, message: RawMessage, exc: Exception, bag: str) -> RejectedNotification:
    headers = {"rosbag": bag, "topic": message.topic, "receiveTime": _iso(message.time_ns)}
    return RejectedNotification(
        plan_.tenant, datetime.now(UTC), UNREADABLE, _words(exc), orjson.dumps(headers).decode(), message.data
    )


def _words(exc: Exception) -> str:
    return getattr(exc, "description", None) or str(exc)


def _iso(time_ns: int) -> str:
    moment = _EPOCH + timedelta(microseconds=time_ns // 1000)
    return moment.isoformat().replace("+00:00", "Z")


__all__ = ["BagError", "ImportNotVerified", "PreparedImport", "RosbagReport", "import_rosbag"]
