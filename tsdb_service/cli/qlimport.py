"""``tsdb-service import quantumleap --from URL --db OUR_DB``: move off QuantumLeap.

The command around ``commands.quantumleap.importer.import_quantumleap`` (the
library call): flags, the checks made before anything is created, and the
printed report. Every refusal is one ``error:`` line and exit status 2.
"""

from __future__ import annotations

import argparse
import re
import sys
from collections.abc import Callable

from tsdb_service.cli.argtypes import positive_int, utc_time
from tsdb_service.cli.newdb import new_duckdb_file
from tsdb_service.core.config import Settings, SettingsError, check_db, load_settings


def register(subparsers, command) -> None:
    p = subparsers.add_parser(
        "import",
        help="import the history another time-series service keeps",
        description="Import history kept by another service, as if its notifications had arrived here.",
    )
    sources = p.add_subparsers(dest="import_source", required=True, metavar="SOURCE")
    ql = sources.add_parser(
        "quantumleap",
        help="import QuantumLeap's tables (TimescaleDB/PostgreSQL or CrateDB)",
        description="Read every QuantumLeap table (one per tenant and entity type) and store each row as the "
        "notification it came from: original attribute names and types, geometries and time indexes kept. "
        "The target must be empty unless --append is given; an interrupted import resumes when the same "
        "command is run again; at the end the totals per tenant and type are checked. "
        "Migration guide: docs/migrate-from-quantumleap.md.",
    )
    ql.add_argument(
        "--from",
        dest="source",
        required=True,
        metavar="URL",
        help="QuantumLeap's database: postgresql://user:pass@host:5432/quantumleap (TimescaleDB), or "
        "postgresql://crate@host:5432/doc (CrateDB's PostgreSQL port)",
    )
    ql.add_argument(
        "--db",
        metavar="PATH|URL",
        help="our store to import into: a DuckDB file or a postgresql:// URL (default ./data/tsdb.duckdb; env TSDB_DB)",
    )
    ql.add_argument(
        "--tenant",
        action="append",
        default=[],
        metavar="TENANT",
        help="only this tenant (FIWARE service; '' for the default tenant); repeat for several (default: every tenant)",
    )
    ql.add_argument(
        "--type",
        dest="types",
        action="append",
        default=[],
        metavar="TYPE",
        help="only this entity type; repeat for several (default: every type)",
    )
    ql.add_argument(
        "--from-date",
        metavar="TIME",
        help="only rows with time_index at or after TIME (ISO 8601; default: from the first)",
    )
    ql.add_argument(
        "--to-date",
        metavar="TIME",
        help="only rows with time_index before TIME (ISO 8601, exclusive; default: to the last)",
    )
    ql.add_argument("--append", action="store_true", help="add to a target that already holds history")
    ql.add_argument("--dry-run", action="store_true", help="report per table what would be imported; write nothing")
    ql.add_argument(
        "--keep-duplicates",
        action="store_true",
        help="import rows QuantumLeap stored twice as often as they are stored (default: once)",
    )
    ql.add_argument(
        "--batch-samples",
        type=positive_int,
        default=50_000,
        metavar="N",
        help="samples committed per batch; an interruption loses at most one (default 50000)",
    )
    ql.add_argument(
        "--max-value-bytes",
        type=positive_int,
        default=9 * 1024 * 1024,
        metavar="N",
        help="largest value (one cell) imported; a larger one is left out and reported, never read "
        "(default 9437184, TSDB_MAX_BODY_BYTES' default: no notification could carry more)",
    )
    ql.add_argument("--quiet", action="store_true", help="no progress line (default: progress on stderr)")
    command("import")(_source_explained(cmd_import))


def cmd_import(args: argparse.Namespace) -> int:
    from tsdb_service.commands.quantumleap.importer import (
        ImportNotVerified,
        Selection,
        import_quantumleap,
    )
    from tsdb_service.commands.quantumleap.reader import SourceUnavailable, Window
    from tsdb_service.storage import open_store, redact

    if not args.source.startswith(("postgresql://", "postgres://")):
        raise SettingsError(f"--from: {args.source!r} is not a postgresql:// URL (CrateDB: its PostgreSQL port, 5432)")
    try:
        db = check_db(args.db) if args.db else load_settings().db
    except ValueError as exc:
        raise SettingsError(f"--db: {exc}") from None
    if Settings(db=db).backend == "postgresql" and redact(db) == redact(args.source):
        raise SettingsError("--from and --db are the same database: import into a store of its own")
    window = Window(utc_time(args.from_date, "--from-date"), utc_time(args.to_date, "--to-date"))
    if window.start and window.end and window.start >= window.end:
        raise SettingsError("--from-date must be before --to-date")
    selection = Selection(tuple(args.tenant), tuple(args.types), window)
    options = {
        "selection": selection,
        "append": args.append,
        "keep_duplicates": args.keep_duplicates,
        "progress": not args.quiet,
        "batch_samples": args.batch_samples,
        "max_value_bytes": args.max_value_bytes,
    }
    if args.dry_run:  # the target is not even opened: nothing is created
        report = import_quantumleap(args.source, None, dry_run=True, **options)
        _print_tables(report, "would import")
        print(f"dry run: {report.samples} samples would be imported; nothing was written")
        return 0
    _check_source(args.source)  # a wrong URL or a database without QuantumLeap: before the target is created
    created = new_duckdb_file(Settings(db=db))
    target = open_store(Settings(db=db))
    if created is not None:
        print(f"created a new, empty DuckDB database at {created}", file=sys.stderr)
    try:
        report = import_quantumleap(args.source, target, **options)
    except ImportNotVerified as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    except SourceUnavailable as exc:  # e.g. the connection lost midway: what is committed stays
        print(f"error: {exc}; run the same command again to resume", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"\ninterrupted: run the same command again to resume the import into {db}", file=sys.stderr)
        return 130
    finally:
        target.close()
    _print_tables(report, "imported")
    timed = f" timed before {window.end.isoformat()}" if window.end else ""
    for (tenant, etype), (rows, samples) in sorted(report.totals.items()):
        print(f"tenant {tenant or '(default)'} type {etype}: the target holds {rows} rows, {samples} samples{timed}")
    if report.resumed_from:
        print(f"resumed an interrupted import: {report.resumed_from} samples were already there")
    print(f"import verified: {report.samples} samples imported")
    return 0


def _source_explained(run: Callable[[argparse.Namespace], int]) -> Callable[[argparse.Namespace], int]:
    """``run`` with a QuantumLeap database that does not exist said in one
    line naming it and how to list the databases there (libpq's words,
    passed on by the importer, name neither the server nor what to do)."""

    def explained(args: argparse.Namespace) -> int:
        try:
            return run(args)
        except RuntimeError as exc:
            line = missing_source_database(str(exc), args.source)
            if line is None:
                raise
            print(f"error: {line}", file=sys.stderr)
            return 2

    return explained


def missing_source_database(message: str, source: str) -> str | None:
    """The one line for a failure to connect to ``source`` because its
    database does not exist; None for any other failure."""
    from urllib.parse import urlsplit

    from tsdb_service.storage import redact

    found = re.search(r'database "([^"]+)" does not exist', message)
    if found is None or redact(source) not in message:
        return None
    parts = urlsplit(source)
    host, port, user = parts.hostname or "localhost", parts.port or 5432, parts.username or "postgres"
    return (
        f"cannot connect to QuantumLeap's database {found[1]!r} on {host}:{port}: there is no database of that "
        f"name. Name an existing one in --from (QuantumLeap's default: quantumleap); psql -h {host} -p {port} "
        f"-U {user} -l lists them"
    )


def _check_source(url: str) -> None:
    from tsdb_service.commands.quantumleap.reader import QuantumLeapReader

    reader = QuantumLeapReader(url)
    try:
        reader.tables()
    finally:
        reader.close()


def _print_tables(report, verb: str) -> None:
    """Per table what was (or would be) imported, then what was not and why:
    tables, attributes, rows and values, each counted, the first few named."""
    for skipped in report.skipped:
        print(f"{skipped.name}: not imported: {skipped.reason}")
    for t in report.tables:
        if t.skipped is not None:
            print(f"{t.name}: {t.source_rows} rows, not imported: {t.skipped}")
            continue
        notes = []
        if t.duplicates:
            notes.append(f"{t.duplicates} duplicate rows")
        if t.recovered:
            notes.append(f"{t.recovered} failed-batch rows recovered")
        if t.unreadable:
            notes.append(f"{t.unreadable} rows not importable")
        if t.refused_attrs:
            notes.append(f"{len(t.refused_attrs)} attributes not importable")
        if t.dropped:
            notes.append(f"{t.dropped} values not importable")
        extra = f" ({', '.join(notes)})" if notes else ""
        print(f"{t.name}: {t.source_rows} rows, {verb} {t.rows} rows, {t.samples} samples{extra}")
        for column, why in sorted(t.refused_attrs.items()):
            print(f"  column {_shown(column)} not imported: {why}")
        for p in t.problems:
            print(f"  not imported: {p.entity_id or '?'} at {p.time_index}: {p.reason}")
        for d in t.dropped_shown:
            print(f"  value not imported: {_shown(d.attr)} of {d.entity_id} at {d.time_index}: {d.reason}")
    refused = len(report.skipped) + sum(t.skipped is not None for t in report.tables)
    if refused:
        print(f"{refused} tables not imported: their tenant or layout is not one the API can serve (see above)")


def _shown(text: str) -> str:
    """A name from QuantumLeap's tables, on one line (newlines and the like escaped)."""
    return repr(text[:120])
