"""Retention: delete raw samples and rollup rows older than their level's limit.

``TSDB_RETENTION`` names how long each level of history is kept, per tenant
and optionally per entity type (``*=365d,acme/Robot=raw:30d,minute:1y``, see
``core.retention_policy``): raw samples, minute rollups, hour rollups. A
background thread (``RetentionWorker``) applies it every
``TSDB_RETENTION_INTERVAL`` seconds in bounded batches: at most
``TSDB_RETENTION_BATCH_ROWS`` rows per batch and table, each batch its own
short transaction, with a pause between batches, so ingest and queries never
wait long behind it.

Rollups are kept up to date on ingest (``storage.rollups``), so deleting raw
samples leaves them: what a coarser level holds is what remains of the
finer ones. Each raw batch records, in its transaction, the newest sample
time it deleted per series (``rollups_expired``): buckets up to there can no
longer be recomputed from raw. A level's batch deletes the rows whose whole
bucket is older than its cutoff.

Each backend batches its own way (a ``Session``, from
``Store.retention_session``):

* **DuckDB** (``storage.duckdb.retention``): a batch holds the compactor's lock (as a user's delete does),
  so it never races the compactor moving or rewriting the same rows; it
  picks at most N expired rows by ``rowid``, deletes them, and drops the
  touched series from the in-memory tails and latest locations.
* **PostgreSQL** (``storage.postgres.retention``): one statement per batch picks at most N expired rows by
  (``tableoid``, ``ctid``) and deletes them, recording what it deleted
  (``RETURNING``). A session advisory lock lets one replica run a pass at a
  time; the others skip theirs. Rollup batches hold the rollup lock.

After a rule's every batch of a level is done, its *watermark* (the cutoff
it applied: every row of the rule and level older than that is gone) is
saved in ``retention_state`` (``tbl``: samples, minute or hour), so the lag
metric survives restarts.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime, timedelta
from typing import Protocol

from tsdb_service.core.retention_policy import HOUR, MINUTE, RAW, RetentionPolicy
from tsdb_service.storage.rollups import HOT, LEVEL_NAMED, ExpiryPresence, Level

log = logging.getLogger(__name__)

SAMPLES = "samples"  # the watermark kind of the raw level (the rollup levels': their names)
KINDS = {RAW: SAMPLES, MINUTE: MINUTE, HOUR: HOUR}


@dataclass(frozen=True)
class RetentionConfig:
    policy: RetentionPolicy = field(default_factory=RetentionPolicy)
    interval: float = 300.0
    batch_rows: int = 50_000
    pause: float = 0.05

    @classmethod
    def from_settings(cls, settings) -> RetentionConfig:
        if settings.rollups:
            log.warning(
                "TSDB_ROLLUPS is deprecated and has no effect: minute and hour rollups are always kept up to date; "
                "how long each level is kept is in TSDB_RETENTION (e.g. acme=raw:30d,minute:1y,hour:forever)"
            )
        if settings.rollup_retention.strip():
            log.warning(
                "TSDB_ROLLUP_RETENTION is deprecated: its rules now apply to both rollup levels; "
                "give them in TSDB_RETENTION instead (TSDB_RETENTION=%s)",
                settings.retention_policy().describe(),
            )
        return cls(
            policy=settings.retention_policy(),
            interval=settings.retention_interval,
            batch_rows=settings.retention_batch_rows,
            pause=settings.retention_pause,
        )

    @property
    def active(self) -> bool:
        return self.policy.active


# --- backends ----------------------------------------------------------------------


class Session(Protocol):
    """One pass's database access (a cursor or connection of its own)."""

    tables: tuple[str, ...]

    def series(self) -> list[tuple[int, str, str]]: ...

    def delete_samples(self, table: str, sids: Sequence[int], cutoff: datetime, limit: int) -> int: ...

    def delete_rollups(self, level: Level, table: str, sids: Sequence[int], cutoff: datetime, limit: int) -> int: ...

    def save_watermark(self, kind: str, rule: str, horizon: datetime) -> None: ...


SAVE_WATERMARK = (
    "INSERT INTO retention_state (tbl, rule, horizon, updated_at) VALUES ({p}, {p}, {p}, {p}) "
    "ON CONFLICT (tbl, rule) DO UPDATE SET horizon = EXCLUDED.horizon, updated_at = EXCLUDED.updated_at"
)


# --- the worker ----------------------------------------------------------------------


class RetentionObserver(Protocol):
    """Told about each batch that deleted rows (``telemetry.RetentionMetrics``)."""

    def batch(self, table: str, tenant: str, rows: int, seconds: float) -> None: ...


class RetentionWorker:
    """Applies the policies in the background; ``run_once`` is one pass."""

    def __init__(self, store, config: RetentionConfig, clock: Callable[[], datetime] | None = None):
        self._store = store
        self.config = config
        self._clock = clock or (lambda: datetime.now(UTC))
        self._session = store.retention_session
        self._stop = threading.Event()
        self._run_lock = threading.Lock()
        self._thread: threading.Thread | None = None
        self.observer: RetentionObserver | None = None
        self.watermarks = store.retention_watermarks()
        self.passes = 0
        self.batches = 0

    def start(self) -> None:
        self._thread = threading.Thread(target=self._loop, name="tsdb-retention", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        """Finish the batch in progress, then stop (no batch is left half done)."""
        self._stop.set()
        if self._thread is not None and self._thread.is_alive():
            self._thread.join()

    def _loop(self) -> None:
        while not self._stop.wait(self.config.interval):
            try:
                self.run_once()
            except Exception:  # keep serving; the next pass retries
                log.exception("retention pass failed; will retry")

    def run_once(self) -> dict[str, int]:
        """One pass over every rule of every level, finest first; returns the
        rows deleted per table."""
        deleted: dict[str, int] = {}
        self._store.sync()  # after every sample acknowledged before the pass (the ingest log)
        with self._run_lock, self._session() as session:
            if session is None:
                return deleted
            now = self._clock()
            series = session.series()
            for level in (RAW, MINUTE, HOUR):
                if not self._apply(session, series, level, now, deleted):
                    break
            self.passes += 1
        return deleted

    def _apply(self, session, series, level: str, now: datetime, deleted: dict[str, int]) -> bool:
        """Every finite rule of one level; False when stopped midway."""
        kind = KINDS[level]
        policy = self.config.policy
        groups: dict[str, dict[str, list[int]]] = {}
        keeps: dict[str, timedelta] = {key: keep for key, named, keep in policy.rules if named == level and keep}
        for sid, tenant, entity_type in series:
            rule, keep = policy.resolve(tenant, entity_type)[level]
            if rule is not None and keep is not None:
                groups.setdefault(rule, {}).setdefault(tenant, []).append(sid)
                keeps[rule] = keep
        for rule in sorted(keeps):
            cutoff = (now - keeps[rule]).astimezone(UTC)
            for tenant, sids in sorted(groups.get(rule, {}).items()):
                tables = session.tables if level == RAW else (LEVEL_NAMED[level].table, HOT)
                for table in tables:
                    if not self._drain(session, level, table, tenant, sids, cutoff, deleted):
                        return False
            session.save_watermark(kind, rule, cutoff)
            self.watermarks[(kind, rule)] = cutoff
        return True

    def _drain(self, session, level, table, tenant, sids, cutoff, deleted) -> bool:
        """Batches until one comes back short; False when stopped."""
        limit = self.config.batch_rows
        while True:
            if self._stop.is_set():
                return False
            start = time.perf_counter()
            if level == RAW:
                n = session.delete_samples(table, sids, cutoff, limit)
            else:
                n = session.delete_rollups(LEVEL_NAMED[level], table, sids, cutoff, limit)
            seconds = time.perf_counter() - start
            self.batches += 1
            label = table if level == RAW or table != HOT else f"{HOT}_{level}"
            if n:
                deleted[label] = deleted.get(label, 0) + n
                if level == RAW:
                    self._store.rollup_presence.mark()
                self._tell(label, tenant, n, seconds)
            if n < limit:
                return True
            if self.config.pause:
                self._stop.wait(self.config.pause)

    def _tell(self, table: str, tenant: str, rows: int, seconds: float) -> None:
        observer = self.observer
        if observer is None:
            return
        try:
            observer.batch(table, tenant, rows, seconds)
        except Exception:  # metrics must never stop retention
            log.exception("retention observer failed")

    def lags(self) -> dict[tuple[str, str], float]:
        """(kind, rule) → seconds the last completed pass's cutoff trails the
        rule's cutoff now (about one interval when all is well); kind:
        samples, minute or hour."""
        now = self._clock()
        out = {}
        for key, level, keep in self.config.policy.rules:
            mark = self.watermarks.get((KINDS[level], key))
            if keep is not None and mark is not None:
                out[(KINDS[level], key)] = max(0.0, ((now - keep) - mark).total_seconds())
        return out


def attach_retention(
    store, settings, *, start: bool = True, clock: Callable[[], datetime] | None = None
) -> RetentionWorker | None:
    """Give ``store`` its expiry presence tracker and, when a policy deletes
    anything, its retention worker (started unless ``start`` is False)."""
    config = RetentionConfig.from_settings(settings)
    store.rollup_presence = ExpiryPresence()
    if not config.active:
        return None
    worker = store.retention = RetentionWorker(store, config, clock)
    log.info("retention: %s", config.policy.describe())
    if start:
        worker.start()
    return worker
