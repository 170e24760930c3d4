"""``tsdb-service rollups rebuild|check`` (``commands.rollups``).

    tsdb-service rollups rebuild [--tenant T] [--type X] [--from ISO] [--to ISO] [--drop-expired] [--db ...]
    tsdb-service rollups check   [--tenant T] [--type X] [--from ISO] [--to ISO] [--samples N] [--db ...]

``rebuild`` prints what it recomputed; ``check`` prints every difference
it found and exits with status 1 if there is any. A refusal is one
``error:`` line and exit status 2. On DuckDB both run beside a stopped
service (DuckDB lets one process open the file); on PostgreSQL beside
running replicas.
"""

from __future__ import annotations

import argparse
import sys
from datetime import UTC, datetime

from tsdb_service.cli.argtypes import integer, positive_int, utc_time
from tsdb_service.cli.settingflags import setting_help
from tsdb_service.core.config import Settings, SettingsError, check_db, load_settings


def register(subparsers, command) -> None:
    p = subparsers.add_parser(
        "rollups",
        help="rebuild or check the minute and hour rollups",
        description="Rollups are kept exact on ingest; these commands recompute them from raw samples "
        "(rebuild) or compare a random sample of buckets with raw (check). Buckets whose raw samples "
        "retention deleted keep their rollups, and check skips them.",
    )
    actions = p.add_subparsers(dest="rollups_action", required=True, metavar="ACTION")
    rebuild = actions.add_parser(
        "rebuild",
        help="recompute rollups from raw samples",
        description="Recompute, from raw samples, every minute and hour bucket of the selected series in the "
        "window that raw samples can still answer for, creating missing ones; whole hours, in one transaction "
        "per day and group of series. Buckets retention emptied keep their rollups unless --drop-expired.",
    )
    _selection(rebuild)
    rebuild.add_argument(
        "--drop-expired",
        action="store_true",
        help="also recompute buckets retention emptied or partly emptied, from what raw is left: "
        "the history only rollups held there is lost (default: keep it)",
    )
    rebuild.add_argument("--quiet", action="store_true", help="no progress line (default: progress on stderr)")
    check = actions.add_parser(
        "check",
        help="compare rollups with raw samples over a random sample of buckets",
        description="Compare, field by field, the rollups of a random sample of minute and hour buckets "
        "(half of them buckets rollups hold, half anywhere in the window) with what their raw samples give; "
        "print every difference, exit status 1 if there is any.",
    )
    _selection(check)
    check.add_argument(
        "--samples", type=positive_int, default=1000, metavar="N", help="buckets to compare (default 1000)"
    )
    check.add_argument("--seed", type=integer, metavar="N", help="the random choice's seed (default: a new one)")
    command("rollups")(cmd_rollups)


def _selection(p: argparse.ArgumentParser) -> None:
    p.add_argument("--db", metavar="PATH|URL", help=setting_help("db"))
    p.add_argument(
        "--tenant", metavar="TENANT", help="only this tenant ('' for the default one; default: every tenant)"
    )
    p.add_argument("--type", dest="entity_type", metavar="TYPE", help="only this entity type (default: every type)")
    p.add_argument("--from", dest="start", metavar="TIME", help="from this time (ISO 8601; default: the first)")
    p.add_argument("--to", dest="end", metavar="TIME", help="up to this time, exclusive (ISO 8601; default: the last)")


def cmd_rollups(args: argparse.Namespace) -> int:
    from tsdb_service.commands.rollups import check_rollups, rebuild_rollups
    from tsdb_service.storage import open_store, require_history

    start, end = utc_time(args.start, "--from"), utc_time(args.end, "--to")
    if start is not None and end is not None and start >= end:
        raise SettingsError("--from must be before --to")
    try:
        db = check_db(args.db) if args.db else load_settings().db
    except ValueError as exc:
        raise SettingsError(f"--db: {exc}") from None
    require_history(db)  # a mistyped path must not become a new, empty database
    settings = Settings(db=db)
    tenant = None if args.tenant is None else args.tenant.lower()
    store = open_store(settings)
    try:
        if args.rollups_action == "rebuild":
            show = None if args.quiet else _progress
            report = rebuild_rollups(
                store, tenant, args.entity_type, start, end, drop_expired=args.drop_expired, progress=show
            )
            if show is not None and report.transactions:
                print(file=sys.stderr)
            if report.start is None:
                print(f"nothing to rebuild: {report.series} series, no sample or rollup in the window")
            else:
                print(
                    f"rebuilt {report.buckets} minute and hour buckets of {report.series} series "
                    f"from {_iso(report.start)} to {_iso(report.end)} in {report.transactions} transactions"
                )
            return 0
        checked = check_rollups(store, tenant, args.entity_type, start, end, samples=args.samples, seed=args.seed)
    finally:
        store.close()
    for d in checked.differences:
        print(f"{d.level} {_iso(d.bucket)} series {d.sid}: {d.column} is {d.rollup!r} in rollups, {d.raw!r} from raw")
    print(
        f"checked {checked.buckets} buckets ({checked.incomplete} skipped: retention deleted some of their "
        f"samples): {len(checked.differences)} differences"
    )
    return 1 if checked.differences else 0


def _progress(report) -> None:
    print(f"\r{report.transactions} transactions, {report.buckets} buckets", end="", file=sys.stderr, flush=True)


def _iso(moment: datetime | None) -> str:
    return "" if moment is None else moment.astimezone(UTC).isoformat().replace("+00:00", "Z")
