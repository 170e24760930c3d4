"""``copy_history``: move all history between backends (``tsdb-service copy``).

Samples are streamed from the source in row-id order, regrouped into the
entity notifications they came from (one ``rid`` = one entity in one
notification), and written through the target's normal writer in batches,
so the target assigns its own ids and keeps its own layout. Values layouts
and rejected notifications come along.

Safe to run again, by design:

* the target must be empty, unless ``--append`` says to add to what it holds
  (a second copy into the same target would otherwise double all history);
* each batch is committed alone, in source order, and the run is recorded in
  the target's ``copy_runs`` table; after an interruption the same command
  resumes where the target's committed samples end;
* at the end the target's totals per tenant must equal what it held before
  plus the source's: totals, not what this run believes it added;
* what only the source's rollups hold (buckets whose raw samples retention
  deleted) replaces the target's rollups of those buckets, which held what
  the copied raw samples rolled up (``storage.rollup_repair``): again,
  running it twice changes nothing. A series with no raw sample left has no
  series in the target to hold it: it is counted and said, not copied.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass
from datetime import UTC
from pathlib import Path

from tsdb_service.core.config import Settings
from tsdb_service.core.model import AttrSample, EntitySample, Geometry, Kind, RejectedNotification
from tsdb_service.core.query import EntityFilter, Scope, StoredSample
from tsdb_service.read.requests import SeriesSelect
from tsdb_service.storage.rollup_repair import expired_history, put_expired_history
from tsdb_service.storage.store import CopyRun, Store
from tsdb_service.write.ops import AppendSamples, PutLayout, RecordRejected

# Everything goes through the seam (``Store``, ``Querier``): the source's
# samples come from ``Querier.stored_samples`` (instance ids stay behind:
# an instanceId names an instance in one store), the bookkeeping from
# ``Store.copy_runs_open`` / ``copy_run_start`` / ``copy_run_finish``.
BATCH_ROWS = 50_000
REJECTED_BATCH = 500


class CopyRefused(RuntimeError):
    """The copy cannot (safely) run; the message says why and what to do."""


class CopyNotVerified(CopyRefused):
    """The copy ran but the target's totals are not what they must be."""


def store_identity(db: str) -> str:
    """What a store is called in ``copy_runs`` and compared by: a DuckDB file's
    absolute path, or the URL without its password."""
    from tsdb_service.storage import redact

    if Settings(db=db).backend == "postgresql":
        return redact(db)
    return db if db == ":memory:" else str(Path(db).resolve())


@dataclass
class CopyReport:
    tenants: dict[str, tuple[int, int]]  # tenant → (source samples, samples this copy put in the target)
    target_total: int
    target_rejected: int
    resumed_from: int = 0  # samples already copied by an interrupted run
    rolled_up_buckets: int = 0  # buckets only the source's rollups held, copied
    rolled_up_left_out: int = 0  # series whose rolled-up history could not be (no raw sample left)


def copy_history(
    source: Store,
    target: Store,
    *,
    source_id: str,
    append: bool = False,
    progress: bool = False,
    batch_rows: int = BATCH_ROWS,
) -> CopyReport:
    """Copy everything not yet copied, verify totals, record the run as finished."""
    src_counts = _counts(source)
    src_total = sum(src_counts.values())
    run = _resume_or_start(target, source_id, src_total, append)
    already = sum(_counts(target).values()) - sum(run.base_counts.values())
    _copy_samples(source, target, skip=already, total=src_total, progress=progress, batch_rows=batch_rows)
    _copy_side_tables(source, target, resumed=already > 0 or _rejected_count(target) > run.base_rejected)
    buckets, left_out = _copy_rolled_up(source, target)
    after, rejected = _counts(target), _rejected_count(target)
    _verify(src_counts, run, after, rejected, _rejected_count(source))
    target.copy_run_finish(source_id)
    tenants = {
        t: (src_counts.get(t, 0), after.get(t, 0) - run.base_counts.get(t, 0)) for t in set(src_counts) | set(after)
    }
    return CopyReport(tenants, sum(after.values()), rejected, already, buckets, left_out)


def _copy_rolled_up(source: Store, target: Store) -> tuple[int, int]:
    """The history only the source's rollups hold, into the target's series
    of the same key: (buckets copied, series left out: none in the target)."""
    keys = _series(source)
    sids = {key: sid for sid, key in _series(target).items()}
    buckets, left_out = 0, set()
    for page in expired_history(source):
        sid = sids.get(keys[page.sid]) if page.sid in keys else None
        if sid is None:
            left_out.add(page.sid)
            continue
        put_expired_history(target, page, sid)
        buckets += len(page.rows)
    return buckets, len(left_out)


def _resume_or_start(target: Store, source_id: str, src_total: int, append: bool) -> CopyRun:
    """The unfinished run from this source to resume, or a new one recorded now."""
    for run in target.copy_runs_open():
        source, source_samples = run.source, run.source_samples
        if source.startswith("quantumleap "):
            raise CopyRefused(
                f"the target holds an interrupted import ({source}): finish it by running that "
                "`tsdb-service import quantumleap` again, or copy into a new, empty target"
            )
        if source != source_id:
            raise CopyRefused(
                f"the target holds an interrupted copy from {source}: resume it with `tsdb-service copy "
                f"--from {source} --to ...`, or copy into a new, empty target"
            )
        if source_samples != src_total:
            raise CopyRefused(
                f"the source changed since the interrupted copy began ({source_samples} samples then, "
                f"{src_total} now): copy into a new, empty target instead"
            )
        return run
    counts, rejected = _counts(target), _rejected_count(target)
    if (counts or rejected) and not append:
        raise CopyRefused(
            f"the target already holds {sum(counts.values())} samples and {rejected} rejected notifications: "
            "copying would add the source's history to them. Give --append to do that on purpose, "
            "or copy into a new, empty target"
        )
    run = CopyRun(source_id, counts, rejected, src_total)
    target.copy_run_start(run)
    return run


def _copy_samples(source: Store, target: Store, *, skip: int, total: int, progress: bool, batch_rows: int) -> None:
    """Stream the source in row-id order, skipping the prefix already copied; one
    committed batch at a time, so the target always holds a prefix of the source."""
    series = _series(source)
    copied, started = skip, time.monotonic()
    batch: list[EntitySample] = []
    rows_in_batch = 0
    for entity, n in _entities(source, series, skip):
        batch.append(entity)
        rows_in_batch += n
        if rows_in_batch >= batch_rows:
            target.write_sync([AppendSamples(batch, dedup=False)])
            copied += rows_in_batch
            batch, rows_in_batch = [], 0
            if progress:
                _show(copied, skip, total, started)
    if batch:
        target.write_sync([AppendSamples(batch, dedup=False)])
        copied += rows_in_batch
    if progress:
        _show(copied, skip, total, started)
        print(file=sys.stderr)


def _series(store: Store) -> dict[int, tuple[str, str, str, str, str, str | None]]:
    """Every series by id: (tenant, service path, entity id, type, attr, datasetId)."""
    reader = store.querier()
    return {
        ref.sid: (tenant, ref.service_path, ref.entity_id, ref.entity_type, ref.attr, ref.dataset_id)
        for tenant in reader.tenants()
        for ref in reader.series(SeriesSelect(Scope(tenant), EntityFilter()))
    }


def _samples(store: Store) -> Iterator[StoredSample]:
    for batch in store.querier().stored_samples(BATCH_ROWS):
        yield from batch


def _entities(source: Store, series: dict, skip: int = 0) -> Iterator[tuple[EntitySample, int]]:
    """Rows regrouped by ``rid`` into the entity notifications they came from,
    after the first ``skip`` rows (which must end on a notification)."""
    current_rid, entity, n, seen, last_skipped = None, None, 0, 0, None
    for row in _samples(source):
        if seen < skip:
            seen += 1
            last_skipped = row[0]
            continue
        rid, sid = row[0], row[1]
        if rid != current_rid:
            if entity is not None:
                yield entity, n
            elif skip and rid == last_skipped:
                raise CopyNotVerified(
                    "the target's samples do not end on a notification of the source: "
                    "copy into a new, empty target instead"
                )
            tenant, path, eid, etype, _, _ = series[sid]
            attrs: list[AttrSample] = []
            entity = EntitySample(tenant, path, eid, etype, row.t.replace(tzinfo=UTC), attrs)
            current_rid, n = rid, 0
        attrs.append(_attr(series[sid][4], series[sid][5], row))
        n += 1
    if entity is not None:
        yield entity, n


def _attr(name: str, dataset_id: str | None, row: StoredSample) -> AttrSample:
    geometry = None
    if row.geo is not None:  # then its position and box are stored too
        box = (row.lon, row.lat, row.min_lon, row.min_lat, row.max_lon, row.max_lat)
        geometry = Geometry(row.geo, *(float(v) for v in box if v is not None))
    return AttrSample(
        name,
        row.atype,
        Kind(row.kind),
        row.num,
        row.txt,
        row.js,
        geometry,
        row.md,
        _utc(row.observed_at),
        _utc(row.created_at),
        _utc(row.modified_at),
        _utc(row.deleted_at),
        dataset_id,
    )


def _utc(moment):
    return None if moment is None else moment.replace(tzinfo=UTC)


def _copy_side_tables(source: Store, target: Store, *, resumed: bool) -> None:
    """Layouts (a put is idempotent) and rejected notifications; after an
    interruption, a rejected notification already in the target is not added again."""
    layouts = [PutLayout(t, sub, layout) for (t, sub), layout in sorted(source.all_layouts().items())]
    if layouts:
        target.write_sync(layouts)
    present = set(_rejected_keys(target)) if resumed else set()
    batch = []
    for rejected in _rejected(source):
        if _key(rejected) in present:
            continue
        batch.append(RecordRejected(rejected))
        if len(batch) >= REJECTED_BATCH:
            target.write_sync(batch)
            batch = []
    if batch:
        target.write_sync(batch)


def _rejected(store: Store) -> Iterator[RejectedNotification]:
    return iter(store.rejected_notifications())


def _rejected_keys(store: Store) -> Iterator[tuple]:
    return (_key(r) for r in _rejected(store))


def _key(r: RejectedNotification) -> tuple:
    return (r.tenant, r.received_at, r.error, r.body)


def _verify(src: dict[str, int], run: CopyRun, after: dict[str, int], rejected: int, src_rejected: int) -> None:
    """Totals: every tenant holds what it held before plus the source's samples."""
    wrong = {
        t: (run.base_counts.get(t, 0) + src.get(t, 0), after.get(t, 0))
        for t in set(src) | set(after) | set(run.base_counts)
        if after.get(t, 0) != run.base_counts.get(t, 0) + src.get(t, 0)
    }
    if wrong:
        detail = ", ".join(
            f"{t or '(default)'}: {want} expected, {got} found" for t, (want, got) in sorted(wrong.items())
        )
        raise CopyNotVerified(
            f"copy NOT verified, the target's samples per tenant are wrong ({detail}); copy into a new, empty target"
        )
    if rejected != run.base_rejected + src_rejected:
        raise CopyNotVerified(
            f"copy NOT verified: {run.base_rejected + src_rejected} rejected notifications "
            f"expected in the target, {rejected} found; copy into a new, empty target"
        )


def _counts(store: Store) -> dict[str, int]:
    return store.querier().sample_counts()


def _rejected_count(store: Store) -> int:
    return store.rejected_count()


def _show(done: int, skipped: int, total: int, started: float) -> None:
    rate = (done - skipped) / max(time.monotonic() - started, 1e-9)
    pct = 100.0 * done / total if total else 100.0
    bar = "#" * int(pct // 4)
    print(f"\r[{bar:<25}] {pct:5.1f}%  {done:,}/{total:,} samples  {rate:,.0f}/s", end="", file=sys.stderr, flush=True)
