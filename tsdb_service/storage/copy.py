"""``tsdb-service copy --from URL --to URL``: move all history between backends.

Samples are streamed from the source in row-id order, regrouped into the
entity notifications they came from (one ``rid`` = one entity in one
notification), and written through the target's normal writer in big
batches, so the target assigns its own ids and keeps its own layout. Values
layouts and rejected notifications come along. At the end the number of
samples per tenant is compared on both sides.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Iterator
from datetime import UTC

from ..config import Settings
from ..model import AttrSample, EntitySample, Geometry, Kind, RejectedNotification
from .base import AppendSamples, PutLayout, RecordRejected, Store

SAMPLE_COLUMNS = (
    "rid, sid, t, kind, atype, num, txt, js, geo, lon, lat, min_lon, min_lat, max_lon, max_lat, md, "
    "observed_at, created_at, modified_at, deleted_at"
)  # instance ids are the target's own: an instanceId names an instance in one store
BATCH_ROWS = 50_000


def register(subparsers, command) -> None:
    p = subparsers.add_parser("copy", help="copy all history from one backend to another")
    p.add_argument("--from", dest="source", required=True, help="DuckDB file or postgresql:// URL to read")
    p.add_argument("--to", dest="target", required=True, help="DuckDB file or postgresql:// URL to write")
    p.add_argument("--quiet", action="store_true", help="no progress line")

    @command("copy")
    def cmd_copy(args) -> int:
        if args.source == args.target:
            print("error: --from and --to are the same store", file=sys.stderr)
            return 2
        from . import open_store

        source = open_store(Settings(db=args.source))
        try:
            target = open_store(Settings(db=args.target))
            try:
                report = copy_history(source, target, progress=not args.quiet)
            finally:
                target.close()
        finally:
            source.close()
        for tenant, (src, dst) in sorted(report.items()):
            print(f"tenant {tenant or '(default)'}: {src} samples in source, {dst} in target")
        bad = {t: c for t, c in report.items() if c[1] < c[0]}
        if bad:
            print(f"error: target has fewer samples than source for {sorted(bad)}", file=sys.stderr)
            return 1
        print("copy verified")
        return 0


def copy_history(source: Store, target: Store, *, progress: bool = False) -> dict[str, tuple[int, int]]:
    """Copy everything; return {tenant: (source samples, target samples)}."""
    reader = source.querier()
    before = _counts(target)
    series = {row[0]: row[1:] for row in reader._fetch(
        "SELECT sid, tenant, service_path, entity_id, entity_type, attr, dataset_id FROM series", [])}
    total = sum(_counts(source).values())
    copied, started = 0, time.monotonic()
    batch: list[EntitySample] = []
    rows_in_batch = 0
    for entity, n in _entities(source, series):
        batch.append(entity)
        rows_in_batch += n
        if rows_in_batch >= BATCH_ROWS:
            target.write_sync([AppendSamples(batch, dedup=False)])
            copied += rows_in_batch
            batch, rows_in_batch = [], 0
            if progress:
                _show(copied, total, started)
    if batch:
        target.write_sync([AppendSamples(batch, dedup=False)])
        copied += rows_in_batch
    if progress:
        _show(copied, total, started)
        print(file=sys.stderr)
    _copy_side_tables(source, target)
    after = _counts(target)
    src = _counts(source)
    return {t: (src.get(t, 0), after.get(t, 0) - before.get(t, 0)) for t in set(src) | set(after)}


def _entities(source: Store, series: dict) -> Iterator[tuple[EntitySample, int]]:
    """Rows regrouped by ``rid`` into the entity notifications they came from."""
    current_rid, entity, n = None, None, 0
    for row in _stream(source, f"SELECT {SAMPLE_COLUMNS} FROM samples_all ORDER BY rid, iid"):
        rid, sid = row[0], row[1]
        if rid != current_rid:
            if entity is not None:
                yield entity, n
            tenant, path, eid, etype, _, _ = series[sid]
            entity = EntitySample(tenant, path, eid, etype, row[2].replace(tzinfo=UTC), [])
            current_rid, n = rid, 0
        entity.attrs.append(_attr(series[sid][4], series[sid][5], row))
        n += 1
    if entity is not None:
        yield entity, n


def _attr(name: str, dataset_id: str | None, row: tuple) -> AttrSample:
    (_, _, _, kind, atype, num, txt, js, geo, lon, lat, mnlon, mnlat, mxlon, mxlat, md,
     observed, created, modified, deleted) = row
    geometry = Geometry(geo, lon, lat, mnlon, mnlat, mxlon, mxlat) if geo is not None else None
    return AttrSample(name, atype, Kind(kind), num, txt, js, geometry, md, _utc(observed), _utc(created),
                      _utc(modified), _utc(deleted), dataset_id)


def _utc(moment):
    return None if moment is None else moment.replace(tzinfo=UTC)


def _stream(store: Store, sql: str) -> Iterator[tuple]:
    """All rows of ``sql`` without holding them in memory at once."""
    if store.backend == "postgresql":
        with store.connection() as conn, conn.transaction(), conn.cursor(name="tsdb_copy") as cur:
            cur.execute(sql)
            while rows := cur.fetchmany(BATCH_ROWS):
                yield from rows
        return
    cur = store.cursor().cursor()  # a private cursor: the thread's one may be in use
    try:
        cur.execute(sql)
        while rows := cur.fetchmany(BATCH_ROWS):
            yield from rows
    finally:
        cur.close()


def _copy_side_tables(source: Store, target: Store) -> None:
    reader = source.querier()
    tenants = [row[0] for row in reader._fetch("SELECT DISTINCT tenant FROM subscriptions", [])]
    ops: list = [PutLayout(t, sub, layout) for t in tenants for sub, layout in source.layouts(t).items()]
    for tenant, received_at, error, description, headers, body, size, truncated in reader._fetch(
        "SELECT tenant, received_at, error, description, headers, body, body_size, body_truncated "
        "FROM rejected_notifications ORDER BY id", []
    ):
        ops.append(RecordRejected(RejectedNotification(
            tenant, received_at.replace(tzinfo=UTC), error, description, headers, bytes(body), size,
            bool(truncated))))
    if ops:
        target.write_sync(ops)


def _counts(store: Store) -> dict[str, int]:
    rows = store.querier()._fetch(
        "SELECT s.tenant, count(*) FROM samples_all x JOIN series s ON s.sid = x.sid GROUP BY s.tenant", [])
    return {tenant: int(n) for tenant, n in rows}


def _show(done: int, total: int, started: float) -> None:
    rate = done / max(time.monotonic() - started, 1e-9)
    pct = 100.0 * done / total if total else 100.0
    bar = "#" * int(pct // 4)
    print(f"\r[{bar:<25}] {pct:5.1f}%  {done:,}/{total:,} samples  {rate:,.0f}/s", end="", file=sys.stderr, flush=True)
