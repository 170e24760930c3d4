"""``tsdb-service export``: write a tenant's history (or part of it) to a file.

The flags are the HTTP endpoint's parameters and headers, and go through
the same parser, so the command and ``GET /v2/export`` select the same
samples. A DuckDB file belongs to one process: while the service has it
open, the export goes through the service's ``GET /v2/export``
(``export_service``), at ``--url`` or found as the file's holder.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from tsdb_service.cli.export_service import ServiceExportError, download, export_url, lock_holder, service_url
from tsdb_service.faces.export.query import ExportFormat
from tsdb_service.parse.request_context import tenant_hint

_FLAGS = (  # (flag, HTTP parameter or header, placeholder, help)
    ("--type", "type", "TYPES", "entity types (comma-separated)"),
    ("--id", "id", "IDS", "entity ids (comma-separated)"),
    ("--id-pattern", "idPattern", "REGEX", "entity id regular expression"),
    ("--attrs", "attrs", "NAMES", "attribute names (comma-separated; default: all)"),
    ("--from-date", "fromDate", "TIME", "first time included (ISO 8601; default: the oldest sample)"),
    ("--to-date", "toDate", "TIME", "last time included (ISO 8601; default: the newest sample)"),
    (
        "--bucket",
        "bucket",
        "WIDTH",
        "one row per series and time bucket of WIDTH (10s, 5min, 1h, 1d ...) with the count, average, minimum, "
        "maximum, first and last of its numbers (default: one row per sample)",
    ),
)
SUFFIXES = {
    ".csv": ExportFormat.CSV,
    ".parquet": ExportFormat.PARQUET,
    ".pq": ExportFormat.PARQUET,
    ".mcap": ExportFormat.MCAP,
}


def register(subparsers, command) -> None:
    p = subparsers.add_parser(
        "export",
        help="export history to a CSV, Parquet or MCAP (Foxglove) file",
        description="Write one row per sample (time, entity, attribute, typed value) of a tenant, "
        "optionally narrowed to types, entities, attributes and a time range.",
    )
    p.add_argument(
        "--db",
        metavar="PATH|URL",
        help="DuckDB file or postgresql:// URL to read (env TSDB_DB; default ./data/tsdb.duckdb)",
    )
    p.add_argument(
        "--out",
        required=True,
        metavar="FILE",
        help="file to write; its suffix (.csv, .parquet, .mcap) picks the format",
    )
    p.add_argument(
        "--format", choices=[f.value for f in ExportFormat], help="csv, parquet or mcap (default: from --out)"
    )
    p.add_argument(
        "--service", default="", metavar="TENANT", help="tenant, as Fiware-Service (default: the default tenant)"
    )
    p.add_argument(
        "--service-path", default="/", metavar="PATH", help="Fiware-ServicePath: paths and their children (default /)"
    )
    p.add_argument(
        "--raw",
        action="store_true",
        help="CSV: write text cells as stored (by default a cell starting with = + - @ tab or CR gets a "
        "leading ' so a spreadsheet does not run it as a formula)",
    )
    for flag, _, metavar, text in _FLAGS:
        p.add_argument(flag, metavar=metavar, help=text if "default" in text else f"{text} (default: all)")
    p.add_argument(
        "--url",
        metavar="URL",
        help="export through the running service at URL (GET /v2/export) instead of opening --db; a credential "
        "comes from the variable TSDB_CLIENT_TOKEN (default: open --db, or, when a tsdb-service on this machine "
        "holds the DuckDB file, export through it)",
    )
    command("export")(cmd_export)


def cmd_export(args: argparse.Namespace) -> int:
    from tsdb_service.core.config import Settings
    from tsdb_service.core.errors import TsdbError
    from tsdb_service.faces.export import export_query, open_export, write_file
    from tsdb_service.parse.request_context import tenant
    from tsdb_service.storage import StoreUnavailable, open_store

    settings = Settings(**({"db": args.db} if args.db else {}))
    if args.url and not args.url.startswith(("http://", "https://")):
        print(f"error: --url {args.url}: give the service's http:// or https:// URL", file=sys.stderr)
        return 2
    if not args.url and settings.backend == "duckdb" and not Path(settings.db).is_file():
        print(f"error: no database at {settings.db}", file=sys.stderr)
        return 2
    try:
        check_out(args.out)
        out_format = chosen_format(args.out, args.format)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    params = {name: getattr(args, flag[2:].replace("-", "_")) for flag, name, _, _ in _FLAGS}
    params = {k: v for k, v in params.items() if v is not None}
    params["format"] = out_format
    if args.raw:
        params["raw"] = "true"
    headers = {"fiware-service": args.service, "fiware-servicepath": args.service_path}
    try:
        query = export_query(params, headers, tenant(headers.items()))
    except TsdbError as exc:
        print(f"error: {exc.description}", file=sys.stderr)
        return 2
    if args.url:
        return _through_service(args.url, params, headers, args.out)
    try:
        store = open_store(settings)
    except StoreUnavailable:
        holder = lock_holder(settings.db) if settings.backend == "duckdb" else None
        if holder is None:
            raise
        return _through_holder(settings.db, holder, params, headers, args.out)
    try:
        with open_export(store, query) as stream:
            rows, size, seconds = write_file(stream, query.format, args.out, query.raw, query.scope.tenant)
        hint = tenant_hint(store.querier().tenants(), query.scope.tenant) if rows == 0 else None
    finally:
        store.close()
    rate = rows / seconds if seconds > 0 else 0.0
    what = "samples" if query.bucket is None else "buckets"
    print(
        f"exported {rows:,} {what} to {args.out} ({size:,} bytes, {query.format.value}) "
        f"in {seconds:.2f} s ({rate:,.0f} {what}/s)"
    )
    if hint:
        print(f"hint: {hint} (--service TENANT)", file=sys.stderr)
    return 0


def _through_holder(db: str, pid: int, params: dict[str, str], headers: dict[str, str], out: str) -> int:
    """The DuckDB file is held by process ``pid``: export through it when it
    is a tsdb-service listening here, else say in one line how to."""
    url = service_url(pid)
    if url is None:
        print(
            f"error: {db} is held by another process (PID {pid}), the running service if it is one: DuckDB lets "
            f"one process open a file. Export through the service: tsdb-service export --url http://HOST:PORT "
            f"with the same flags, or GET {export_url('http://HOST:PORT', params)}",
            file=sys.stderr,
        )
        return 2
    print(f"{db} is held by the service at {url} (PID {pid}): exporting through it", file=sys.stderr)
    return _through_service(url, params, headers, out)


def _through_service(url: str, params: dict[str, str], headers: dict[str, str], out: str) -> int:
    try:
        size, seconds = download(url, params, headers, out)
    except ServiceExportError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(f"exported {export_url(url, params)} to {out} ({size:,} bytes) in {seconds:.2f} s")
    return 0


def check_out(out: str) -> None:
    """``ValueError`` if ``--out`` cannot be written: checked before the
    database is opened, so a typo costs nothing."""
    path = Path(out)
    if path.is_dir():
        raise ValueError(f"--out {out} is a directory: give a file name, e.g. {path / 'history.csv'}")
    folder = path.parent
    if not folder.is_dir():
        raise ValueError(f"--out {out}: the directory {folder} does not exist")
    if not os.access(folder, os.W_OK | os.X_OK):
        raise ValueError(f"--out {out}: the directory {folder} is not writable")


def chosen_format(out: str, flag: str | None) -> str:
    """``--format`` where given, else the one ``--out``'s suffix names; a
    ``ValueError`` when the suffix names another format than the flag (a
    ``.csv`` file must not hold MCAP). A suffix that names none (``.json``,
    ``.dat``) is the user's choice of name."""
    if flag is None:
        return format_of(out)
    named = SUFFIXES.get(Path(out).suffix.lower())
    if named is not None and named.value != flag:
        raise ValueError(f"--out {out} names {named.value} but --format says {flag}: make them agree")
    return flag


def format_of(out: str) -> str:
    """The format named by ``--out``'s suffix; ``ValueError`` for any other
    suffix (a ``.json`` file must not silently hold CSV)."""
    suffix = Path(out).suffix.lower()
    if suffix not in SUFFIXES:
        problem = (
            f"the suffix {suffix!r} names no export format" if suffix else "a name without a suffix says no format"
        )
        raise ValueError(
            f"--out {out}: {problem}; end it in .csv, .parquet or .mcap, or give --format csv|parquet|mcap"
        )
    return SUFFIXES[suffix].value
