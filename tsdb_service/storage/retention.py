"""Retention: delete raw samples older than a tenant's (or type's) limit.

``TSDB_RETENTION`` names how long samples are kept, per tenant and
optionally per entity type (``*=365d,acme=30d,acme/Robot=7d``, see
``RetentionPolicy``). A background thread (``RetentionWorker``) applies it
every ``TSDB_RETENTION_INTERVAL`` seconds in bounded batches: at most
``TSDB_RETENTION_BATCH_ROWS`` rows per batch and table, each batch its own
short transaction, with a pause between batches, so ingest and queries never
wait long behind it.

With ``TSDB_ROLLUPS`` each batch folds the rows it deletes into hourly
rollups in the same transaction (``storage.rollups``), and aggregation
queries keep answering for that time. ``TSDB_ROLLUP_RETENTION`` limits how
long rollup rows are kept, with the same syntax.

Each backend batches its own way (a ``Session``, from
``Store.retention_session``):

* **DuckDB** (``storage.duckdb.retention``): a batch holds the compactor's lock (as a user's delete does),
  so it never races the compactor moving or rewriting the same rows; it
  picks at most N expired rows by ``rowid``, folds them, deletes them, and
  drops the touched series from the in-memory tails and latest locations.
* **PostgreSQL** (``storage.postgres.retention``): one statement per batch picks at most N expired rows by
  (``tableoid``, ``ctid``), deletes them and folds exactly the rows it
  deleted (``RETURNING``). A session advisory lock lets one replica run a
  pass at a time; the others skip theirs.

After a rule's every batch is done, its *watermark* (the cutoff it applied:
every sample of the rule older than that is gone, and folded when rollups
are on) is saved in ``retention_state``, so the lag metric survives
restarts.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime, timedelta
from typing import Protocol

from tsdb_service.core.retention_policy import RetentionPolicy
from tsdb_service.storage.rollups import TABLE as ROLLUP_TABLE
from tsdb_service.storage.rollups import RollupPresence
from tsdb_service.storage.sql.dialect import SqlDialect

log = logging.getLogger(__name__)

SAMPLES, ROLLUPS = "samples", "rollups"  # the two things retention trims


@dataclass(frozen=True)
class RetentionConfig:
    samples: RetentionPolicy = field(default_factory=RetentionPolicy)
    rollups: bool = False
    rollup_policy: RetentionPolicy = field(default_factory=RetentionPolicy)
    interval: float = 300.0
    batch_rows: int = 50_000
    pause: float = 0.05

    @classmethod
    def from_settings(cls, settings) -> RetentionConfig:
        return cls(
            samples=RetentionPolicy.parse(settings.retention, "TSDB_RETENTION"),
            rollups=settings.rollups,
            rollup_policy=RetentionPolicy.parse(settings.rollup_retention, "TSDB_ROLLUP_RETENTION"),
            interval=settings.retention_interval,
            batch_rows=settings.retention_batch_rows,
            pause=settings.retention_pause,
        )

    @property
    def active(self) -> bool:
        return self.samples.active or self.rollup_policy.active


# --- backends ----------------------------------------------------------------------


class Session(Protocol):
    """One pass's database access (a cursor or connection of its own)."""

    tables: tuple[str, ...]

    def series(self) -> list[tuple[int, str, str]]: ...

    def delete_samples(self, table: str, sids: Sequence[int], cutoff: datetime, limit: int, fold: bool) -> int: ...

    def delete_rollups(self, sids: Sequence[int], cutoff: datetime, limit: int) -> int: ...

    def save_watermark(self, kind: str, rule: str, horizon: datetime) -> None: ...


def rollup_delete_sql(dialect: SqlDialect, sids: Sequence[int], cutoff: datetime, limit: int) -> tuple[str, list]:
    """At most ``limit`` rollup rows of ``sids`` older than ``cutoff`` (by key: the primary key finds them)."""
    where, params = dialect.sid_filter(sids)
    p = dialect.placeholder
    sql = (
        f"DELETE FROM {ROLLUP_TABLE} WHERE (sid, bucket) IN (SELECT sid, bucket FROM {ROLLUP_TABLE} "
        f"WHERE {where} AND bucket < {p} LIMIT {p})"
    )
    return sql, [*params, dialect.time_value(cutoff), limit]


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
        """One pass over every rule; returns the rows deleted per table."""
        deleted: dict[str, int] = {}
        self._store.sync()  # after every sample acknowledged before the pass (the ingest log)
        with self._run_lock, self._session() as session:
            if session is None:
                return deleted
            now = self._clock()
            series = session.series()
            if self._apply(session, series, SAMPLES, now, deleted):
                self._apply(session, series, ROLLUPS, now, deleted)
            self.passes += 1
        return deleted

    def _apply(self, session, series, kind: str, now: datetime, deleted: dict[str, int]) -> bool:
        """Every finite rule of one policy; False when stopped midway."""
        policy = self.config.samples if kind == SAMPLES else self.config.rollup_policy
        groups: dict[str, dict[str, list[int]]] = {}
        for sid, tenant, entity_type in series:
            found = policy.rule_for(tenant, entity_type)
            if found is not None and found[1] is not None:
                groups.setdefault(found[0], {}).setdefault(tenant, []).append(sid)
        for rule, keep in policy.rules:
            if keep is None:
                continue
            cutoff = self._cutoff(now, keep, hourly=kind == ROLLUPS or self.config.rollups)
            for tenant, sids in sorted(groups.get(rule, {}).items()):
                tables = session.tables if kind == SAMPLES else (ROLLUP_TABLE,)
                for table in tables:
                    if not self._drain(session, kind, table, tenant, sids, cutoff, deleted):
                        return False
            session.save_watermark(kind, rule, cutoff)
            self.watermarks[(kind, rule)] = cutoff
        return True

    @staticmethod
    def _cutoff(now: datetime, keep: timedelta, hourly: bool) -> datetime:
        """Rows older than this go. With rollups, on an hour boundary: an
        hour is then folded whole, never partly raw and partly rolled up."""
        cutoff = (now - keep).astimezone(UTC)
        if hourly:
            return cutoff.replace(minute=0, second=0, microsecond=0)
        return cutoff

    def _drain(self, session, kind, table, tenant, sids, cutoff, deleted) -> bool:
        """Batches until one comes back short; False when stopped."""
        limit = self.config.batch_rows
        while True:
            if self._stop.is_set():
                return False
            start = time.perf_counter()
            if kind == SAMPLES:
                n = session.delete_samples(table, sids, cutoff, limit, self.config.rollups)
            else:
                n = session.delete_rollups(sids, cutoff, limit)
            seconds = time.perf_counter() - start
            self.batches += 1
            if n:
                deleted[table] = deleted.get(table, 0) + n
                if kind == SAMPLES and self.config.rollups:
                    self._store.rollup_presence.mark()
                self._tell(table, tenant, n, seconds)
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
        rule's cutoff now (about one interval when all is well). With rollups
        the samples' lag is also the rollups' watermark lag: every sample
        older than the watermark is in the rollups."""
        now = self._clock()
        out = {}
        for kind, policy in ((SAMPLES, self.config.samples), (ROLLUPS, self.config.rollup_policy)):
            for rule, keep in policy.rules:
                mark = self.watermarks.get((kind, rule))
                if keep is not None and mark is not None:
                    out[(kind, rule)] = max(0.0, ((now - keep) - mark).total_seconds())
        return out


def attach_retention(
    store, settings, *, start: bool = True, clock: Callable[[], datetime] | None = None
) -> RetentionWorker | None:
    """Give ``store`` its rollup presence tracker and, when a policy deletes
    anything, its retention worker (started unless ``start`` is False)."""
    config = RetentionConfig.from_settings(settings)
    store.rollup_presence = RollupPresence(enabled=config.rollups)
    if not config.active:
        if config.rollups:
            log.info("rollups are on but no retention rule deletes anything: nothing to roll up")
        return None
    worker = store.retention = RetentionWorker(store, config, clock)
    log.info(
        "retention: samples %s, rollups %s (kept %s)",
        config.samples.describe(),
        "on" if config.rollups else "off",
        config.rollup_policy.describe(),
    )
    if start:
        worker.start()
    return worker
