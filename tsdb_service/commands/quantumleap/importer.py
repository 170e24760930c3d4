"""``import_quantumleap``: QuantumLeap's history into our store, as if notified.

Every row of QuantumLeap's tables becomes the ``EntitySample`` its
notification would have made (``rows``) and goes through the write seam
(``AppendSamples``), as ``/v2/notify`` and ``copy`` write. Safe the way
``copy`` is (``commands.copy``), and with its bookkeeping (``copy_runs``):

* a target that holds history is refused unless ``append``;
* tables are read in (tenant, table) order, each in ``time_index`` order,
  and committed in batches that never split one table's instant; the run
  is recorded in ``copy_runs`` under a source name that includes the
  filters, so the same command after an interruption resumes: it skips as
  many samples as the target gained since the run began (always a prefix of
  this order) and writes the rest, without duplicates;
* at the end the target's (entity notifications, samples) per tenant and
  type must equal what it held before plus what the import read: totals,
  not what this run believes it wrote.

With ``--to-date``, resuming and the check count only samples timed before
it, so the gap after switching Orion can be imported into a serving
target. Without it they count everything: the target must then be written
by nobody else while the import runs (a resume would otherwise skip as
many samples as others wrote).

``copy_runs.base_counts`` holds ``{"rows<TAB>tenant<TAB>type": n,
"samples<TAB>tenant<TAB>type": n}`` for an import.

Duplicate rows (QuantumLeap does not deduplicate; a duplicate differs only
in ``instanceid``) are counted and imported once, unless ``keep_duplicates``.
Rows that cannot be imported (a failed batch's unparseable entity, a row
with every attribute NULL, no usable ``time_index``, an entity id, type or
service path the API refuses) are counted and reported with the first few;
so are tables (a tenant the API refuses, a malformed ``md_ets_metadata``
entry, a table without QuantumLeap's columns), attributes (a name the API
refuses, a column the table lacks) and single values (larger than
``max_value_bytes``, a time Python cannot hold, a NUL). Whatever the
tables hold, the import ends in a report or one error line, never a
traceback, in bounded memory (``reader``; batches are cut by bytes too).
"""

from __future__ import annotations

import sys
import time
from collections import defaultdict
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from datetime import datetime

from tsdb_service.commands.inorder import InOrder
from tsdb_service.commands.quantumleap.reader import (
    MAX_VALUE_BYTES,
    PAGE_ROWS,
    REFUSED_CELLS,
    QuantumLeapReader,
    Window,
)
from tsdb_service.commands.quantumleap.rows import (
    HOUSEKEEPING,
    ID,
    ORIGINAL_ENTITY,
    TIME_INDEX,
    TYPE,
    Dropped,
    SkippedTable,
    TableMeta,
    Unreadable,
    duplicate_key,
    iso,
    row_to_entity,
    to_datetime,
)
from tsdb_service.core.model import EntitySample
from tsdb_service.storage.store import CopyRun, Store
from tsdb_service.write.ops import AppendSamples

BATCH_SAMPLES = 50_000
BATCH_BYTES = 64 * 1024 * 1024  # a batch is committed once its values weigh this much, whatever its samples
SHOWN_PROBLEMS = 5
_REQUIRED = (ID, TYPE, TIME_INDEX)  # a table without them is not QuantumLeap's
PROGRESS_EVERY_S = 0.5
_SEP = "\t"


class ImportRefused(RuntimeError):
    """The import cannot (safely) run; the message is one line saying why and what to do."""


class ImportNotVerified(ImportRefused):
    """The import ran but the target's totals are not what they must be."""


@dataclass
class TableReport:
    """What one QuantumLeap table gave (or, in a dry run, would give)."""

    name: str
    tenant: str
    source_rows: int = 0
    rows: int = 0  # entity notifications imported
    samples: int = 0
    recovered: int = 0  # failed-batch rows imported from their original entity
    duplicates: int = 0  # rows not imported again
    unreadable: int = 0
    problems: list[Unreadable] = field(default_factory=list)
    by_type: dict[str, list[int]] = field(default_factory=dict)  # type as notified → [rows, samples]
    refused_attrs: dict[str, str] = field(default_factory=dict)  # column → why it is not imported
    dropped: int = 0  # single values left out of rows that were imported
    dropped_shown: list[Dropped] = field(default_factory=list)
    skipped: str | None = None  # why nothing of the table is imported


@dataclass
class ImportReport:
    tables: list[TableReport]
    dry_run: bool
    totals: dict[tuple[str, str], tuple[int, int]] = field(default_factory=dict)  # checked in the target
    resumed_from: int = 0  # samples already imported by an interrupted run
    skipped: list[SkippedTable] = field(default_factory=list)  # md_ets_metadata entries not imported

    @property
    def samples(self) -> int:
        return sum(t.samples for t in self.tables)


@dataclass(frozen=True)
class Selection:
    """Which part of QuantumLeap's history to import."""

    tenants: tuple[str, ...] = ()  # "" is the default tenant; empty: all
    types: tuple[str, ...] = ()  # entity types, as notified; empty: all
    window: Window = field(default_factory=Window)

    def keeps(self, meta: TableMeta) -> bool:
        tenants = {t.lower() for t in self.tenants}
        types = {t.lower() for t in self.types}
        return (not tenants or meta.tenant in tenants) and (not types or meta.entity_type in types)

    def describe(self) -> str:
        parts = [f"tenant={','.join(sorted(self.tenants))}" if self.tenants else ""]
        parts.append(f"type={','.join(sorted(self.types))}" if self.types else "")
        parts.append(f"from={self.window.start.isoformat()}" if self.window.start else "")
        parts.append(f"to={self.window.end.isoformat()}" if self.window.end else "")
        return " ".join(p for p in parts if p)


def import_quantumleap(
    source_url: str,
    target: Store | None,
    *,
    selection: Selection = Selection(),
    append: bool = False,
    dry_run: bool = False,
    keep_duplicates: bool = False,
    progress: bool = False,
    batch_samples: int = BATCH_SAMPLES,
    page_rows: int = PAGE_ROWS,
    max_value_bytes: int = MAX_VALUE_BYTES,
) -> ImportReport:
    """Import QuantumLeap's history from ``source_url`` into ``target`` (not
    touched, and may be None, when ``dry_run``); the report, verified."""
    reader = QuantumLeapReader(source_url)
    try:
        tables = [m for m in reader.tables() if selection.keeps(m)]
        skipped = list(reader.skipped)
        if not tables and skipped:
            raise ImportRefused(
                f"{reader.where} has no QuantumLeap table that can be imported: "
                + "; ".join(f"{t.name}: {t.reason}" for t in skipped[:SHOWN_PROBLEMS])
            )
        if not tables:
            raise ImportRefused(
                f"{reader.where} has no QuantumLeap table for {selection.describe() or 'any tenant and type'}"
            )
        source_rows = {m.name: reader.count(m, selection.window) for m in tables}
        run = None
        if not dry_run:
            if target is None:
                raise ValueError("a target store is needed unless dry_run")
            source_id = _source_id(reader.where, selection, keep_duplicates)
            run = _resume_or_start(target, source_id, sum(source_rows.values()), append, selection.window.end)
        job = _Job(reader, target, run, selection.window.end, keep_duplicates, progress, batch_samples, page_rows)
        job.max_value_bytes = max_value_bytes
        reports = job.run(tables, source_rows, selection.window)
    finally:
        reader.close()
    report = ImportReport(reports, dry_run, resumed_from=job.skip, skipped=skipped)
    if target is not None and run is not None:
        report.totals = _verify(target, run, reports, selection.window.end)
        target.copy_run_finish(run.source)
    return report


def _source_id(where: str, selection: Selection, keep_duplicates: bool) -> str:
    """The run's name in ``copy_runs``: the source and everything that decides what is imported."""
    parts = [f"quantumleap {where}", selection.describe(), "keep-duplicates" if keep_duplicates else ""]
    return " ".join(p for p in parts if p)


def _resume_or_start(target: Store, source_id: str, source_rows: int, append: bool, before: datetime | None) -> CopyRun:
    for run in target.copy_runs_open():
        if run.source != source_id:
            raise ImportRefused(
                f"the target holds an interrupted import or copy ({run.source}): finish it by running that "
                "command again, or import into a new, empty target"
            )
        if run.source_samples != source_rows:
            raise ImportRefused(
                f"QuantumLeap's tables changed since the interrupted import began ({run.source_samples} rows then, "
                f"{source_rows} now): give --to-date to import a span that no longer changes, into a new, empty target"
            )
        return run
    counts = target.querier().type_counts()
    if counts and not append:
        samples = sum(n for _, n in counts.values())
        raise ImportRefused(
            f"the target already holds {samples} samples: importing would add QuantumLeap's history to them. "
            "Give --append to do that on purpose (e.g. to import the gap after switching Orion), "
            "or import into a new, empty target"
        )
    base: dict[str, int] = {}
    for (tenant, etype), (rows, samples) in target.querier().type_counts(before).items():
        base[_SEP.join(("rows", tenant, etype))] = rows
        base[_SEP.join(("samples", tenant, etype))] = samples
    run = CopyRun(source_id, base, target.rejected_count(), source_rows)
    target.copy_run_start(run)
    return run


class _Job:
    """One pass over the selected tables: convert, deduplicate, count, write."""

    def __init__(
        self,
        reader: QuantumLeapReader,
        target: Store | None,
        run: CopyRun | None,
        before: datetime | None,
        keep_duplicates: bool,
        progress: bool,
        batch_samples: int,
        page_rows: int,
    ):
        self.reader, self.target, self.run_record, self.keep_duplicates = reader, target, run, keep_duplicates
        self.progress, self.batch_samples, self.page_rows = progress, batch_samples, page_rows
        self.before = before  # --to-date: what is timed later is not this import's
        self.skip = 0
        self.seen = 0  # samples passed, skipped or written
        self.batch: list[EntitySample] = []
        self.batch_bytes = 0
        self.max_value_bytes = MAX_VALUE_BYTES
        self.writes = InOrder(target.write_sync if target is not None else lambda ops: None, "ql-import")
        self.batch_n = 0
        self.rows_done = 0
        self.rows_total = 0
        self.started = time.monotonic()
        self.shown = 0.0

    def run(self, tables: Sequence[TableMeta], source_rows: dict[str, int], window: Window) -> list[TableReport]:
        if self.target is not None and self.run_record is not None:
            self.skip = _already(self.target, self.run_record, self.before)
        self.rows_total = sum(source_rows.values())
        reports = []
        try:
            for meta in tables:
                report = TableReport(meta.name, meta.tenant, source_rows[meta.name])
                reports.append(report)
                columns = self._columns(meta, report)
                if columns is None:
                    continue
                self._untimed(meta, window, report)
                pages = self.reader.pages(meta, columns, window, self.page_rows, self.max_value_bytes)
                for group in _instants(pages):
                    self._group(meta, group, report)
            self._flush(last=True)
        finally:
            self.writes.close()  # a batch in flight (e.g. at Ctrl-C) ends committed or not, never half
        if self.progress:
            self._show(final=True)
            print(file=sys.stderr)
        if self.seen < self.skip:
            raise ImportNotVerified(
                f"the target gained {self.skip} samples since the interrupted import began, more than "
                f"QuantumLeap's tables hold ({self.seen}): import into a new, empty target instead"
            )
        return reports

    def _columns(self, meta: TableMeta, report: TableReport) -> list[str] | None:
        """The columns to read; None (and ``report.skipped`` says why) when
        the table lacks QuantumLeap's own. Attributes md_ets_metadata names
        that are refused, or missing from the table, are reported."""
        present = set(self.reader.columns(meta))
        missing = [c for c in _REQUIRED if c not in present]
        if missing:
            report.skipped = f"the table has no {', '.join(missing)} column: not a QuantumLeap table"
            report.unreadable = report.source_rows
            return None
        report.refused_attrs.update(meta.refused)
        for column, (name, _) in meta.attrs.items():
            if column not in present:
                report.refused_attrs[column] = (
                    f"attribute {name[:80]!r}: md_ets_metadata names it, the table has no such column"
                )
        wanted = (HOUSEKEEPING - {"instanceid"}) | set(meta.attrs)
        return sorted(c for c in wanted if c in present)

    def _untimed(self, meta: TableMeta, window: Window, report: TableReport) -> None:
        """Rows without a usable time index: counted, never read."""
        n = self.reader.untimed(meta, window)
        if n:
            report.unreadable += n
            why = "time_index is NULL, infinity or outside the years 1 to 9999"
            report.problems.append(Unreadable(meta.name, f"{n} rows", "-", why))

    def _group(self, meta: TableMeta, rows: list[dict], report: TableReport) -> None:
        """One instant of one table: its entities, each duplicate once."""
        entities, seen = [], set()
        for row in rows:
            dropped: list[Dropped] = []
            entity = _refused_cells(meta, row, dropped) or row_to_entity(meta, row, self.reader.dialect, dropped)
            if dropped:
                report.dropped += len(dropped)
                report.dropped_shown += dropped[: SHOWN_PROBLEMS - len(report.dropped_shown)]
            if isinstance(entity, Unreadable):
                report.unreadable += 1
                if len(report.problems) < SHOWN_PROBLEMS:
                    report.problems.append(entity)
                continue
            key = duplicate_key(entity)
            if key in seen:
                report.duplicates += 1
                if not self.keep_duplicates:
                    continue
            seen.add(key)
            entities.append(entity)
            report.recovered += row.get(ORIGINAL_ENTITY) is not None and _only_original(meta, row)
        n = 0
        for entity in entities:
            counts = report.by_type.setdefault(entity.entity_type, [0, 0])
            counts[0] += 1
            counts[1] += len(entity.attrs)
            n += len(entity.attrs)
        report.rows += len(entities)
        report.samples += n
        self.rows_done += len(rows)
        if self.seen + n <= self.skip:  # committed by the interrupted run
            self.seen += n
            return
        if self.seen < self.skip:
            raise ImportNotVerified(
                "the target's samples do not end where a batch of this import ends: "
                "import into a new, empty target instead"
            )
        self.seen += n
        if self.target is None:
            self._show()
            return
        self.batch.extend(entities)
        self.batch_n += n
        self.batch_bytes += sum(_weight(e) for e in entities)
        if self.batch_n >= self.batch_samples or self.batch_bytes >= BATCH_BYTES:
            self._flush()

    def _flush(self, last: bool = False) -> None:
        """Commit the batch in the background while the next one is read
        (one at a time, in order: the target always holds a prefix)."""
        batch, self.batch, self.batch_n, self.batch_bytes = self.batch, [], 0, 0
        if batch and self.target is not None:
            self.writes.submit([AppendSamples(batch, dedup=False)])  # once the previous batch is committed
        if last:
            self.writes.wait()
        else:
            self._show()

    def _show(self, final: bool = False) -> None:
        now = time.monotonic()
        if not self.progress or (now < self.shown + PROGRESS_EVERY_S and not final):
            return
        self.shown = now
        rate = (self.seen - self.skip) / max(time.monotonic() - self.started, 1e-9)
        pct = 100.0 * self.rows_done / self.rows_total if self.rows_total else 100.0
        print(
            f"\r[{'#' * int(pct // 4):<25}] {pct:5.1f}%  {self.rows_done:,}/{self.rows_total:,} rows  "
            f"{self.seen:,} samples  {rate:,.0f} samples/s",
            end="",
            file=sys.stderr,
            flush=True,
        )


def _refused_cells(meta: TableMeta, row: dict, dropped: list[Dropped]) -> Unreadable | None:
    """The cells the reader left out of ``row`` (``REFUSED_CELLS``): an
    attribute's value is dropped (the rest of the row imported); the
    entity's own columns make the row unreadable."""
    refused = row.pop(REFUSED_CELLS, None)
    if not refused:
        return None
    moment = to_datetime(row.get(TIME_INDEX))
    at = iso(moment) if moment is not None else str(row.get(TIME_INDEX))
    eid = row.get(ID) if isinstance(row.get(ID), str) else None
    for column, why in refused:
        if column in meta.attrs:
            dropped.append(Dropped(meta.attrs[column][0], (eid or "?")[:200], at, why))
        elif column != ORIGINAL_ENTITY or not any(row.get(c) is not None for c in meta.attrs):
            return Unreadable(meta.name, eid and eid[:200], at, f"column {column}: {why}")
    return None


def _weight(entity: EntitySample) -> int:
    """About what an entity's values weigh in memory, for cutting batches."""
    return sum(64 + len(a.txt or "") + len(a.js or "") for a in entity.attrs)


def _only_original(meta: TableMeta, row: dict) -> bool:
    return all(row.get(c) is None for c in meta.attrs)


def _instants(pages: Iterator[list[dict]]) -> Iterator[list[dict]]:
    """Rows grouped by ``time_index`` (pages never split one)."""
    for page in pages:
        group: list[dict] = []
        current: datetime | None = None
        for row in page:
            if group and row["time_index"] != current:
                yield group
                group = []
            current = row["time_index"]
            group.append(row)
        if group:
            yield group


def _already(target: Store, run: CopyRun, before: datetime | None) -> int:
    """Samples the interrupted run committed: the target's gain since it began
    (timed before ``--to-date``: a serving target's new notifications are later)."""
    base = sum(n for key, n in run.base_counts.items() if key.startswith("samples" + _SEP))
    return sum(n for _, n in target.querier().type_counts(before).values()) - base


def _verify(
    target: Store, run: CopyRun, reports: list[TableReport], before: datetime | None
) -> dict[tuple[str, str], tuple[int, int]]:
    """Per tenant and type: the target holds what it held before plus what was
    read. With ``--to-date``, only what is timed before it is compared: a
    serving target (the gap imported after switching Orion) receives newer
    notifications meanwhile."""
    read: dict[tuple[str, str], list[int]] = defaultdict(lambda: [0, 0])
    for kind, n in run.base_counts.items():
        what, tenant, etype = kind.split(_SEP)
        read[tenant, etype][0 if what == "rows" else 1] += n
    for key, (rows, samples) in _imported_by_type(reports).items():
        read[key][0] += rows
        read[key][1] += samples
    after = target.querier().type_counts(before)
    wrong = {
        key: (tuple(want), after.get(key, (0, 0)))
        for key, want in read.items()
        if tuple(want) != after.get(key, (0, 0))
    }
    wrong.update({key: ((0, 0), got) for key, got in after.items() if key not in read})
    if wrong:
        detail = ", ".join(
            f"{tenant or '(default)'}/{etype}: {want[0]} rows and {want[1]} samples expected, "
            f"{got[0]} and {got[1]} found"
            for (tenant, etype), (want, got) in sorted(wrong.items())
        )
        late = " (notifications timed before --to-date that reached the target meanwhile count too)" if before else ""
        raise ImportNotVerified(f"import NOT verified, the target's totals are wrong ({detail}){late}")
    return after


def _imported_by_type(reports: list[TableReport]) -> dict[tuple[str, str], tuple[int, int]]:
    out: dict[tuple[str, str], tuple[int, int]] = {}
    for report in reports:
        for etype, (rows, samples) in report.by_type.items():
            have = out.get((report.tenant, etype), (0, 0))
            out[report.tenant, etype] = (have[0] + rows, have[1] + samples)
    return out
