"""``tsdb-service replay``: stored history sent again, in time order, to a broker or another service.

The command around ``commands.replay``: the selection (the export's flags,
parsed by the same request parsers), one target, pacing, the tenant rule,
and the printed report. A refusal is one ``error:`` line and exit status 2;
a target that refuses midway, one line and exit status 1 (the report says
up to which time history was sent).
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading
import uuid
from pathlib import Path

from tsdb_service.cli.argtypes import positive_number

_SELECTION = (  # (flag, HTTP parameter, placeholder, help)
    ("--type", "type", "TYPES", "entity types (comma-separated)"),
    ("--id", "id", "IDS", "entity ids (comma-separated)"),
    ("--id-pattern", "idPattern", "REGEX", "entity id regular expression"),
    ("--attrs", "attrs", "NAMES", "attribute names (comma-separated)"),
    ("--from-date", "fromDate", "TIME", "first time replayed (ISO 8601)"),
    ("--to-date", "toDate", "TIME", "last time replayed (ISO 8601)"),
)
_TARGETS = ("to_orion", "to_orion_ld", "to_mqtt", "to_notify")


def register(subparsers, command) -> None:
    p = subparsers.add_parser(
        "replay",
        help="send stored history again, in time order, to Orion, Orion-LD, MQTT or another tsdb-service",
        description="Read a tenant's history (or part of it) and send it again as the updates it came from, in "
        "time order, at real speed or a factor of it: to a staging broker whose dashboards relive an incident, "
        "to an MQTT topic, or to another tsdb-service. Every update carries the attribute tsdbReplay (this replay, "
        "its source, the original time). The tenant read from is never written to unless --force. "
        "Guide: docs/robots.md.",
    )
    source = p.add_argument_group("what to replay")
    source.add_argument("--db", metavar="PATH|URL", help="store to read (env TSDB_DB; default ./data/tsdb.duckdb)")
    source.add_argument(
        "--url",
        metavar="URL",
        help="read through the running service at URL (GET /v2/export) instead of opening --db (a credential "
        "from TSDB_CLIENT_TOKEN) (default: open --db, or the tsdb-service on this machine that holds the DuckDB file)",
    )
    source.add_argument("--service", default="", metavar="TENANT", help="tenant to read (default: the default tenant)")
    source.add_argument(
        "--service-path", default="/", metavar="PATH", help="service paths and their children (default /)"
    )
    for flag, _, metavar, text in _SELECTION:
        source.add_argument(flag, metavar=metavar, help=f"{text} (default: all)")
    target = p.add_argument_group("where to send it (one of)")
    target.add_argument(
        "--to-orion", metavar="URL", help="an Orion: POST /v2/op/update (e.g. http://orion:1026; default: none)"
    )
    target.add_argument(
        "--to-orion-ld", metavar="URL", help="an Orion-LD: POST /ngsi-ld/v1/entityOperations/upsert (default: none)"
    )
    target.add_argument(
        "--to-mqtt", metavar="URL", help="an MQTT broker (mqtt://HOST:1883), as Orion publishes (default: none)"
    )
    target.add_argument(
        "--to-notify", metavar="URL", help="another tsdb-service: POST /v2/notify (its base URL; default: none)"
    )
    target.add_argument(
        "--to-service",
        metavar="TENANT",
        help="tenant to send to (default: the one read; refused unless --force)",
    )
    target.add_argument("--to-service-path", metavar="PATH", help="service path to send to (default: each update's)")
    target.add_argument(
        "--mqtt-topic",
        default=None,
        metavar="TEMPLATE",
        help="with --to-mqtt: topic (default tsdb/${service}${servicePath})",
    )
    target.add_argument(
        "--mqtt-shape",
        choices=("orion", "orion-ld"),
        default="orion",
        help="with --to-mqtt: the bare notification Orion publishes, or Orion-LD's {metadata, body} (default orion)",
    )
    target.add_argument(
        "--mqtt-username",
        default="",
        metavar="USER",
        help="with --to-mqtt: user, password from TSDB_MQTT_PASSWORD (default: none)",
    )
    pace = p.add_argument_group("pace")
    pace.add_argument(
        "--speed",
        type=positive_number,
        default=1.0,
        metavar="FACTOR",
        help="times real speed (default 1; 10: ten times)",
    )
    pace.add_argument("--no-pacing", action="store_true", help="send as fast as the target takes it")
    pace.add_argument(
        "--retime",
        action="store_true",
        help="stamp each update with the time it is sent (TimeInstant / observedAt), so live dashboards show it; "
        "the original time stays in the marker (default: the original times)",
    )
    pace.add_argument("--force", action="store_true", help="allow sending into the tenant read from")
    pace.add_argument("--quiet", action="store_true", help="no progress line (default: progress on stderr)")
    command("replay")(cmd_replay)


def cmd_replay(args: argparse.Namespace) -> int:
    from tsdb_service.commands.replay.runner import ReplayRefused, check_tenants
    from tsdb_service.core.errors import TsdbError

    try:
        selection, params, headers = _selection(args)
        chosen = [name for name in _TARGETS if getattr(args, name)]
        if len(chosen) != 1:
            raise ReplayRefused("give one target: --to-orion, --to-orion-ld, --to-mqtt or --to-notify URL")
        _check_target(args, chosen[0])
        to_tenant = selection.scope.tenant if args.to_service is None else _tenant(args.to_service)
        to_path = _path(args.to_service_path) if args.to_service_path else None
        check_tenants(selection.scope.tenant, to_tenant, args.force)
    except (ReplayRefused, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except TsdbError as exc:
        print(f"error: {exc.description}", file=sys.stderr)
        return 2
    return _run(args, selection, params, headers, to_tenant, to_path)


def _selection(args: argparse.Namespace):
    from tsdb_service.commands.replay.source import Selection
    from tsdb_service.faces.export.query import export_query
    from tsdb_service.parse.request_context import tenant

    params = {name: getattr(args, flag[2:].replace("-", "_")) for flag, name, _, _ in _SELECTION}
    params = {k: v for k, v in params.items() if v is not None}
    headers = {"fiware-service": args.service, "fiware-servicepath": args.service_path}
    query = export_query(params, headers, tenant(headers.items()))  # the export's parser: the same selection
    return Selection(query.scope, query.entities, query.attrs, query.time), params, headers


def _check_target(args: argparse.Namespace, chosen: str) -> None:
    from urllib.parse import urlsplit

    from tsdb_service.core.config import check_mqtt_url

    url = getattr(args, chosen)
    flag = "--" + chosen.replace("_", "-")
    if chosen == "to_mqtt":
        check_mqtt_url(url)
        return
    parts = urlsplit(url)
    if parts.scheme not in ("http", "https") or not parts.hostname or "@" in parts.netloc:
        raise ValueError(f"{flag} {url[:80]!r}: give the receiver's http:// or https:// base URL, without credentials")
    if args.mqtt_topic or args.mqtt_username or args.mqtt_shape != "orion":
        raise ValueError("--mqtt-topic, --mqtt-shape and --mqtt-username go with --to-mqtt")


def _tenant(text: str) -> str:
    from tsdb_service.parse.request_context import TenantProblem, select_tenant

    try:
        return select_tenant([("--to-service", text)] if text.strip() else [])
    except TenantProblem as exc:
        raise ValueError(f"--to-service: {exc}") from None


def _path(text: str) -> str:
    from tsdb_service.parse.names import normalize_service_path, service_path_problem

    path = normalize_service_path(text.strip())
    problem = service_path_problem(path)
    if problem is not None:
        raise ValueError(f"--to-service-path {path[:80]!r} {problem}")
    return path


def _target(args: argparse.Namespace):
    from tsdb_service.commands.replay import targets

    if args.to_orion:
        return targets.OrionTarget(args.to_orion)
    if args.to_orion_ld:
        return targets.OrionLdTarget(args.to_orion_ld)
    if args.to_notify:
        return targets.NotifyTarget(args.to_notify)
    topic = args.mqtt_topic or targets.MQTT_TOPIC
    return targets.MqttTarget(args.to_mqtt, topic, args.mqtt_shape == "orion-ld", args.mqtt_username)


def _run(args, selection, params, headers, to_tenant: str, to_path: str | None) -> int:
    from tsdb_service.commands.replay.runner import replay
    from tsdb_service.commands.replay.source import SourceError
    from tsdb_service.commands.replay.targets import Marker, ReplayError

    store = None
    try:
        store, updates, where = _source(args, selection, params, headers)
        target = _target(args)
    except (ReplayError, SourceError, ValueError) as exc:
        if store is not None:
            store.close()
        print(f"error: {exc}", file=sys.stderr)
        return 2
    marker = Marker(uuid.uuid4().hex[:12], f"{selection.scope.tenant or '(default tenant)'} on {where}")
    pace = "as fast as it takes them" if args.no_pacing else f"at x{args.speed:g}"
    into = f"tenant {to_tenant or '(default)'}"
    print(f"replaying {marker.source} to {target.name}, {into}, {pace} (replay {marker.replay})")
    stop = threading.Event()
    previous = signal.signal(signal.SIGINT, lambda *_: stop.set())
    try:
        report = replay(
            updates,
            target,
            marker,
            tenant=to_tenant,
            service_path=to_path,
            speed=None if args.no_pacing else args.speed,
            retime=args.retime,
            stop=stop,
            progress=None if args.quiet else _progress(),
        )
    except (ReplayError, SourceError) as exc:
        print(f"\nerror: {exc}", file=sys.stderr)
        return 1
    finally:
        signal.signal(signal.SIGINT, previous)
        target.close()
        if store is not None:
            store.close()
    if not args.quiet:
        print(file=sys.stderr)
    _print(report)
    return 130 if report.stopped else 0


def _source(args, selection, params, headers):
    """(store or None, updates, where): the store opened here, or the service holding it."""
    from tsdb_service.cli.export_service import lock_holder, service_url
    from tsdb_service.commands.replay.source import SourceError, service_updates, store_updates
    from tsdb_service.core.config import Settings
    from tsdb_service.storage import StoreUnavailable, open_store, redact

    if args.url:
        if not args.url.startswith(("http://", "https://")):
            raise SourceError(f"--url {args.url[:80]}: give the service's http:// or https:// URL")
        return None, service_updates(args.url, params, headers), args.url
    settings = Settings(**({"db": args.db} if args.db else {}))
    if settings.backend == "duckdb" and not Path(settings.db).is_file():
        raise SourceError(f"no database at {settings.db}")  # opening would create an empty one
    try:
        store = open_store(settings)
    except StoreUnavailable:
        holder = lock_holder(settings.db) if settings.backend == "duckdb" else None
        url = service_url(holder) if holder is not None else None
        if url is None:
            raise
        print(f"{settings.db} is held by the service at {url} (PID {holder}): reading through it", file=sys.stderr)
        return None, service_updates(url, params, headers), url
    where = redact(settings.db) if settings.backend == "postgresql" else settings.db
    return store, store_updates(store, selection), where


def _progress():
    import time

    shown = [0.0]

    def show(report) -> None:
        now = time.monotonic()
        if now - shown[0] < 0.5:
            return
        shown[0] = now
        print(
            f"\r{report.updates:,} updates ({report.samples:,} samples), history at {report.last:%Y-%m-%d %H:%M:%S}, "
            f"{report.late_max:.3f} s late at most",
            end="",
            file=sys.stderr,
            flush=True,
        )

    return show


def _print(report) -> None:
    if not report.updates:
        print("nothing to replay: the selection holds no samples")
        return
    span = (report.last - report.first).total_seconds()
    print(
        f"replayed {report.updates} updates ({report.samples} samples, {report.sends} sends) of history from "
        f"{report.first.isoformat()} to {report.last.isoformat()} ({span:.1f} s) in {report.seconds:.1f} s"
    )
    if report.lateness:
        print(f"pacing: {report.late_mean * 1000:.1f} ms late on average, {report.late_max * 1000:.1f} ms at most")
    if report.stopped:
        print(f"stopped: history after {report.last.isoformat()} was not sent (--from-date to go on from there)")
