"""``tsdb-service copy --from URL --to URL``: move all history between backends.

The command around ``commands.copy.copy_history`` (the library call): flags,
the checks made before anything is opened, and the printed report. A
refusal is one ``error:`` line and exit status 2; a copy whose totals do not
check out, status 1.
"""

from __future__ import annotations

import sys

from tsdb_service.cli.argtypes import positive_int
from tsdb_service.commands.copy import BATCH_ROWS, CopyNotVerified, CopyRefused, copy_history, store_identity
from tsdb_service.core.config import Settings, check_db


def register(subparsers, command) -> None:
    p = subparsers.add_parser(
        "copy",
        help="copy all history from one backend to another",
        description="Copy every sample, 'values' layout and rejected notification from --from into --to, "
        "then check the totals. The target must be empty unless --append is given. An interrupted copy "
        "resumes when the same command is run again.",
    )
    p.add_argument(
        "--from",
        dest="source",
        required=True,
        metavar="PATH|URL",
        help="DuckDB file or postgresql:// URL to read; must exist and hold tsdb-service history",
    )
    p.add_argument(
        "--to",
        dest="target",
        required=True,
        metavar="PATH|URL",
        help="DuckDB file or postgresql:// URL to write (created if it is a new DuckDB file)",
    )
    p.add_argument(
        "--append",
        action="store_true",
        help="add to a target that already holds history (default: refuse a non-empty target)",
    )
    p.add_argument(
        "--batch-rows",
        type=positive_int,
        default=BATCH_ROWS,
        metavar="ROWS",
        help=f"samples committed per batch; an interruption loses at most one (default {BATCH_ROWS})",
    )
    p.add_argument("--quiet", action="store_true", help="no progress line (default: progress on stderr)")
    command("copy")(cmd_copy)


def cmd_copy(args) -> int:
    from tsdb_service.storage import open_store, require_history

    source_db, target_db = _checked(args.source, "--from"), _checked(args.target, "--to")
    if store_identity(source_db) == store_identity(target_db):
        raise CopyRefused("--from and --to are the same store")
    require_history(source_db)
    source = open_store(Settings(db=source_db))
    try:
        target = open_store(Settings(db=target_db))
        try:
            report = copy_history(
                source,
                target,
                source_id=store_identity(source_db),
                append=args.append,
                progress=not args.quiet,
                batch_rows=args.batch_rows,
            )
        except CopyNotVerified as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 1
        except KeyboardInterrupt:
            print(f"\ninterrupted: run the same command again to resume the copy into {target_db}", file=sys.stderr)
            return 130
        finally:
            target.close()
    finally:
        source.close()
    for tenant, (src, dst) in sorted(report.tenants.items()):
        print(f"tenant {tenant or '(default)'}: {src} samples in source, {dst} copied into target")
    if report.resumed_from:
        print(f"resumed an interrupted copy: {report.resumed_from} samples were already there")
    if report.rolled_up_buckets:
        print(f"rollups: {report.rolled_up_buckets} minute and hour buckets whose raw samples retention deleted")
    if report.rolled_up_left_out:
        print(
            f"not copied: the rolled-up history of {report.rolled_up_left_out} series with no raw sample left "
            "(the target has no series to hold it)"
        )
    print(
        f"copy verified: the target holds {report.target_total} samples, "
        f"{report.target_rejected} rejected notifications"
    )
    return 0


def _checked(db: str, flag: str) -> str:
    try:
        return check_db(db)
    except ValueError as exc:
        raise CopyRefused(f"{flag}: {exc}") from None
