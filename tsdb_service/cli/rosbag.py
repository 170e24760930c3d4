"""``tsdb-service import rosbag BAG --db DB [--map MAP]``: a robot's recording into history.

The command around ``commands.rosbag.importer.import_rosbag``: flags, the
printed report, one ``error:`` line (exit status 2) for a bag, a map or a
store that cannot be used, exit status 1 when the totals do not check out.
"""

from __future__ import annotations

import argparse
import sys

from tsdb_service.cli.argtypes import positive_int


def register(subparsers, command) -> None:
    """``rosbag`` under ``import`` (``cli.qlimport`` makes the ``import`` command)."""
    del command  # dispatched by ``import`` through ``run_import``
    importer = subparsers.choices["import"]
    sources = next(a for a in importer._actions if isinstance(a, argparse._SubParsersAction))
    p = sources.add_parser(
        "rosbag",
        help="import a robot's recording: a ROS 2 bag (sqlite3 or mcap), a ROS 1 bag, or a JSON MCAP file",
        description="Store every message of a recording as the ROS 2 IoT Agent and Orion would have: by default "
        "each topic one entity (urn:ngsi-ld:ROS2Topic:...), each message one Object attribute holding it as "
        "JSON, at its header.stamp (else the bag's receive time). --map says otherwise. No ROS installation "
        "is needed: message definitions come from the bag. Importing the same bag again stores nothing twice; "
        "an interrupted import resumes when run again; the totals are checked. Guide: docs/robots.md.",
    )
    p.add_argument("bag", metavar="BAG", help="a rosbag2 directory, a .db3 or .mcap file, or a ROS 1 .bag")
    p.add_argument(
        "--db",
        metavar="PATH|URL",
        help="store to import into: a DuckDB file or a postgresql:// URL (default ./data/tsdb.duckdb; env TSDB_DB)",
    )
    p.add_argument(
        "--map",
        metavar="FILE",
        help="YAML or TOML: which topic becomes which entity (id, type, tenant, service path) and which fields "
        "which attributes (default: one entity per topic, the message as one attribute)",
    )
    p.add_argument("--service", metavar="TENANT", help="tenant of the entities the map does not place (default: none)")
    p.add_argument("--service-path", metavar="PATH", help="service path of those entities (default /)")
    p.add_argument(
        "--again",
        action="store_true",
        help="import a bag this store holds already once more (after deleting what it stored); by default a "
        "second import stores nothing",
    )
    p.add_argument("--dry-run", action="store_true", help="read and check the bag and the map; write nothing")
    p.add_argument(
        "--batch-samples",
        type=positive_int,
        default=50_000,
        metavar="N",
        help="samples committed per batch; an interruption loses at most one (default 50000)",
    )
    p.add_argument("--quiet", action="store_true", help="no progress line (default: progress on stderr)")
    p.set_defaults(run_import=cmd_import_rosbag)


def cmd_import_rosbag(args: argparse.Namespace) -> int:
    from tsdb_service.cli.newdb import new_duckdb_file
    from tsdb_service.commands.rosbag.bag import BagError
    from tsdb_service.commands.rosbag.importer import ImportNotVerified, PreparedImport
    from tsdb_service.commands.rosbag.mapping import MapError, load_map
    from tsdb_service.core.config import Settings, SettingsError, check_db, load_settings
    from tsdb_service.storage import open_store

    try:
        db = check_db(args.db) if args.db else load_settings().db
    except ValueError as exc:
        raise SettingsError(f"--db: {exc}") from None
    defaults = {k: v for k, v in (("service", args.service), ("service_path", args.service_path)) if v is not None}
    try:
        spec = load_map(args.map) if args.map else {}
        # the bag and the map are read and checked before the store is even opened
        prepared = PreparedImport.open(args.bag, spec, f"map {args.map}" if args.map else "the map", defaults)
    except (BagError, MapError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    with prepared:
        if args.dry_run:
            _print_plan(prepared.report)
            print(f"dry run: {prepared.report.total} messages would be imported; nothing was written")
            return 0
        if not prepared.report.total:  # nothing to write: no store to open, let alone create
            _print_plan(prepared.report)
            _print_result(prepared.report)
            return 0
        created = new_duckdb_file(Settings(db=db))
        target = open_store(Settings(db=db))
        if created is not None:
            print(f"created a new, empty DuckDB database at {created}", file=sys.stderr)
        try:
            report = prepared.run(target, again=args.again, progress=not args.quiet, batch_samples=args.batch_samples)
        except ImportNotVerified as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 1
        except KeyboardInterrupt:
            print(f"\ninterrupted: run the same command again to resume the import into {db}", file=sys.stderr)
            return 130
        finally:
            target.close()
    _print_plan(report)
    _print_result(report)
    return 0


def _print_plan(report) -> None:
    print(f"{report.bag} ({report.kind}): {report.total} messages on {len(report.plan.topics)} topics")
    for name, plan in sorted(report.plan.topics.items()):
        attrs = ", ".join(f.name for f in plan.fields)
        where = f"{plan.tenant or '(default tenant)'}{plan.service_path}"
        counts = report.topics[name]
        done = f": {counts.messages} messages, {counts.samples} samples" if counts.messages else ""
        print(f"  {name} -> {plan.entity_id} ({plan.entity_type}) in {where}: {attrs}{done}")
    if report.plan.skipped:
        print(f"  skipped: {', '.join(report.plan.skipped)}")


def _print_result(report) -> None:
    if report.complete_before:
        print(
            f"this store holds this bag's import already ({report.total} messages): nothing was stored again "
            "(--again imports it once more, e.g. after deleting it)"
        )
        return
    if not report.total:
        print("nothing to import: the topics the map imports hold no messages")
        return
    if report.already:
        print(f"resumed an interrupted import: {report.already} messages were stored already")
    if report.unstamped:
        print(f"{report.unstamped} messages had no readable stamp: stored at their receive time")
    if report.rejected:
        print(f"{report.rejected} messages could not be decoded: kept in the rejected store (GET /v2/notify/rejected)")
        for problem in report.problems:
            print(f"  not imported: {problem}")
    for (tenant, etype), samples in sorted(report.totals.items()):
        print(f"tenant {tenant or '(default)'} type {etype}: the target holds {samples} samples of these entities")
    seconds = max(report.seconds, 1e-9)
    print(
        f"import verified: {report.messages} messages, {report.samples} samples in {report.seconds:.2f} s "
        f"({report.messages / seconds:,.0f} messages/s, {report.samples / seconds:,.0f} samples/s)"
    )
