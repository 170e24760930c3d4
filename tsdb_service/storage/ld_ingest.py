"""NGSI-LD instance rules shared by the backends' appenders.

Two things happen to NGSI-LD samples between parsing and storage:

* **Re-notified instances are stored once.** Orion-LD notifies every
  attribute of an entity, the unchanged ones with their old ``observedAt``.
  An instance whose series' latest stored instance has the same
  ``observedAt`` and the same value (kind, value columns, sub-properties,
  deletion) is dropped. ``LatestInstances`` remembers that latest instance
  key per series, like the other in-memory caches never ahead of the
  database: an appender keeps what it staged to itself and publishes it
  only after its commit; a series it does not know is looked up in the
  database (one query per batch). Instances without ``observedAt`` are
  never dropped: nothing says they repeat an earlier one.
* **Entity deletions become instances.** An ``EntitySample`` with
  ``deleted_at`` gets a deletion instance (value ``urn:ngsi-ld:null``,
  stored as kind NULL) for every stored attribute of the entity it does not
  name itself, so ``timeproperty=deletedAt`` finds every attribute.

Exactness: with one writer thread (DuckDB's default) a re-notified instance
is never stored twice. Several writer threads or PostgreSQL replicas each
keep their own cache, so two copies of one instance that arrive at the same
moment on two writers can both be stored; readers see two identical
instances, never a lost one.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterable, Sequence
from datetime import UTC, datetime

from tsdb_service.core.model import AttrSample, EntitySample, Kind

_EPOCH = datetime(1970, 1, 1, tzinfo=UTC)

# (observedAt in epoch microseconds, hash of the value): equal keys mean
# "the same instance again". None: the latest instance has no observedAt.
InstanceKey = tuple[int, int] | None
_MISSING = object()


def micros(moment: datetime) -> int:
    """Exact epoch microseconds of an aware or naive-UTC datetime."""
    if moment.tzinfo is None:
        moment = moment.replace(tzinfo=UTC)
    delta = moment - _EPOCH
    return (delta.days * 86_400 + delta.seconds) * 1_000_000 + delta.microseconds


def instance_key(observed_at, kind, num, txt, js, md, deleted) -> InstanceKey:
    """The identity of an instance's content; the same from a parsed sample
    and from a stored row (numbers hash alike as int or float)."""
    if observed_at is None:
        return None
    return micros(observed_at), hash((int(kind), num, txt, js, md, bool(deleted)))


def sample_key(attr: AttrSample) -> InstanceKey:
    return instance_key(attr.observed_at, attr.kind, attr.num, attr.txt, attr.js, attr.md, attr.deleted_at is not None)


class LatestInstances:
    """Series id → key of its latest stored instance, bounded (oldest
    entries out first; an evicted series is looked up again when needed)."""

    def __init__(self, capacity: int = 1_000_000):
        self.capacity = capacity
        self._keys: dict[int, InstanceKey] = {}
        self._lock = threading.Lock()

    def get(self, sid: int):
        """The key, or ``LatestInstances.MISSING`` when the series is not cached."""
        return self._keys.get(sid, _MISSING)

    MISSING = _MISSING

    def publish(self, keys: dict[int, InstanceKey]) -> None:
        """After a commit: these are now the latest stored instances."""
        if not keys:
            return
        with self._lock:
            store = self._keys
            for sid, key in keys.items():
                store.pop(sid, None)
                store[sid] = key
            overflow = len(store) - self.capacity
            if overflow > 0:
                for sid in list(store)[:overflow]:
                    del store[sid]

    def drop(self, sids: Iterable[int]) -> None:
        """Series whose instances were deleted or changed: look them up again."""
        with self._lock:
            for sid in sids:
                self._keys.pop(sid, None)


def drop_renotified(
    items: Sequence[tuple[tuple, int | None, AttrSample, bool]],
    cache: LatestInstances,
    staged: dict[tuple, InstanceKey],
    load: Callable[[list[int]], dict[int, InstanceKey]],
) -> list[bool]:
    """Which of ``items`` to keep, in order. An item is (series key, series
    id or None for a series not stored yet, sample, may it be dropped).
    ``staged`` holds this transaction's own latest keys by series key (so a
    series created in this transaction counts too) and is updated with
    every item; publish it with ``publish_staged`` after the commit."""
    missing = sorted(
        {
            sid
            for skey, sid, attr, _ in items
            if sid is not None and attr.observed_at is not None and skey not in staged and cache.get(sid) is _MISSING
        }
    )
    loaded = load(missing) if missing else {}
    keep = []
    for skey, sid, attr, droppable in items:
        key = sample_key(attr)
        if droppable and key is not None:
            latest = staged[skey] if skey in staged else _MISSING if sid is None else loaded.get(sid, cache.get(sid))
            if latest is not _MISSING and latest == key:
                staged[skey] = latest  # what the database holds (or will, at commit)
                keep.append(False)
                continue
        staged[skey] = key
        keep.append(True)
    return keep


def without_dropped(entities: Sequence[EntitySample], keep: Iterable[bool]) -> list[EntitySample]:
    """``entities`` without the attributes ``keep`` (one flag per attribute,
    in order, as ``drop_renotified`` gives them) drops; an entity left
    without attributes goes too."""
    flags = iter(keep)
    out = []
    for e in entities:
        attrs = [a for a in e.attrs if next(flags)]
        if attrs:
            out.append(
                e
                if len(attrs) == len(e.attrs)
                else EntitySample(
                    e.tenant, e.service_path, e.entity_id, e.entity_type, e.time_index, attrs, e.deleted_at, e.rid
                )
            )
    return out


def publish_staged(cache: LatestInstances, staged: dict[tuple, InstanceKey], sid_of: Callable[[tuple], int | None]):
    """After a commit: the staged keys become the cache's."""
    if staged:
        cache.publish({sid: key for skey, key in staged.items() if (sid := sid_of(skey)) is not None})


def with_deletions(
    entities: Sequence[EntitySample],
    attrs_of: Callable[[EntitySample], list[tuple[str, str | None]]],
) -> list[EntitySample]:
    """``entities`` with every entity deletion expanded into deletion
    instances of the entity's stored attributes (``attrs_of`` lists them as
    (stored name, datasetId))."""
    if not any(e.deleted_at is not None for e in entities):
        return list(entities)
    out = []
    for entity in entities:
        if entity.deleted_at is None:
            out.append(entity)
            continue
        named = {a.name for a in entity.attrs}
        extra = [
            AttrSample(name, None, Kind.NULL, deleted_at=entity.deleted_at, dataset_id=dataset)
            for name, dataset in attrs_of(entity)
            if name not in named
        ]
        out.append(
            EntitySample(
                entity.tenant,
                entity.service_path,
                entity.entity_id,
                entity.entity_type,
                entity.time_index,
                [*entity.attrs, *extra],
                entity.deleted_at,
                entity.rid,
            )
        )
    return out


def latest_keys(rows: Iterable[tuple]) -> dict[int, InstanceKey]:
    """Keys from rows (sid, observed_at, kind, num, txt, js, md, deleted_at)."""
    return {row[0]: instance_key(row[1], row[2], row[3], row[4], row[5], row[6], row[7] is not None) for row in rows}


# The latest stored instance of each listed series (by row time, then
# arrival), in the shape ``latest_keys`` reads. ``{sids}`` is the dialect's
# series filter.
LATEST_INSTANCE_SQL = (
    "SELECT sid, observed_at, kind, num, txt, js, md, deleted_at FROM ("
    "SELECT sid, observed_at, kind, num, txt, js, md, deleted_at, "
    "row_number() OVER (PARTITION BY sid ORDER BY t DESC, iid DESC) AS rn "
    "FROM {table} WHERE {sids}) latest WHERE rn = 1"
)
