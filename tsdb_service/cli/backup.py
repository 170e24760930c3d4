"""``tsdb-service backup`` and ``tsdb-service restore`` (``commands.backup``).

    tsdb-service backup --db FILE OUT          beside a stopped DuckDB store
    tsdb-service backup --url URL [NAME]       through the running service
    tsdb-service restore BACKUP --db NEWFILE   a backup becomes a new store

Each prints what it wrote and what it checked (row counts per table, a
sample of rows value by value). A refusal is one ``error:`` line and exit
status 2; a copy that does not check out (and so was not kept), status 1.
"""

from __future__ import annotations

import argparse
import os
import sys

API_KEY_VARIABLE = "TSDB_BACKUP_API_KEY"


def register(subparsers, command) -> None:
    backup = subparsers.add_parser(
        "backup",
        help="take a consistent, checked copy of a DuckDB store",
        description="Copy a DuckDB store with everything acknowledged up to now, then read the copy back "
        "(row counts per table, a sample of rows). Beside a stopped store: --db FILE OUT. While the service "
        "runs (it holds the file): --url URL [NAME], and the service writes NAME in its TSDB_BACKUP_DIR. "
        "PostgreSQL: pg_dump or pg_basebackup (docs/operations.md, 'Backups').",
    )
    where = backup.add_mutually_exclusive_group(required=True)
    where.add_argument("--db", metavar="FILE", help="the DuckDB file of a stopped store (no default: --db or --url)")
    where.add_argument(
        "--url", metavar="URL", help="the running service, e.g. http://localhost:8668 (no default: --db or --url)"
    )
    backup.add_argument(
        "target",
        nargs="?",
        metavar="OUT|NAME",
        help="with --db: the new file to write; with --url: a file name in the service's TSDB_BACKUP_DIR "
        "(default: one with the time in it)",
    )
    backup.add_argument(
        "--api-key",
        metavar="KEY",
        help=f"with --url: an admin API key or token (env {API_KEY_VARIABLE}); not needed without authentication",
    )
    command("backup")(cmd_backup)

    restore = subparsers.add_parser(
        "restore",
        help="make a new DuckDB store from a backup",
        description="Copy a backup to a new DuckDB file (never over an existing file, its WAL or its ingest "
        "log), give it a new database id, and check it against the backup. Start the service on it.",
    )
    restore.add_argument("backup", metavar="BACKUP", help="a file written by tsdb-service backup")
    restore.add_argument("--db", required=True, metavar="NEWFILE", help="the new DuckDB file to make")
    command("restore")(cmd_restore)


def cmd_backup(args: argparse.Namespace) -> int:
    from tsdb_service.commands.backup import backup_stopped, backup_through

    if args.db is not None and not args.target:
        return _refused("backup --db FILE needs OUT, the new file to write")
    if args.db is not None:
        return _run(lambda: backup_stopped(args.db, args.target), "backup")
    key = args.api_key or os.environ.get(API_KEY_VARIABLE)
    return _run(lambda: backup_through(args.url, args.target, key), "backup")


def cmd_restore(args: argparse.Namespace) -> int:
    from tsdb_service.commands.backup import restore

    return _run(lambda: restore(args.backup, args.db), "restore")


def _run(take, what: str) -> int:
    from tsdb_service.core.backup import BackupNotVerified
    from tsdb_service.core.errors import TsdbError

    try:
        report = take()
    except BackupNotVerified as exc:
        print(f"error: {exc.description}", file=sys.stderr)
        return 1
    except TsdbError as exc:
        return _refused(exc.description)
    for line in report.lines(what):
        print(line)
    return 0


def _refused(reason: str) -> int:
    print(f"error: {reason}", file=sys.stderr)
    return 2
