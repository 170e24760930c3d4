"""CLI: ``demo``, ``subscribe``, ``queries run|build`` and ``notifications build``.

Imports of the simulators and HTTP clients happen inside the commands, so
``tsdb-service serve`` does not pay for them at start-up.
"""

from __future__ import annotations

import argparse
import asyncio
import random
import signal
import sys
from datetime import datetime, timedelta
from pathlib import Path

from tsdb_service.cli.argtypes import integer, port, positive_int, positive_number

USE_CASE_NAMES = ("lawnmower", "warehouse", "drone")


def register(subparsers, command) -> None:
    """Add this feature's subcommands to the ``tsdb-service`` parser."""
    _add_demo(subparsers)
    _add_subscribe(subparsers)
    _add_queries(subparsers)
    _add_notifications(subparsers)
    for name, fn in (
        ("demo", cmd_demo),
        ("subscribe", cmd_subscribe),
        ("queries", cmd_queries),
        ("notifications", cmd_notifications),
    ):
        command(name)(fn)


# -- parsers


def _add_demo(sub) -> None:
    p = sub.add_parser(
        "demo",
        help="run the service and the three use-case simulators (the one-command demo)",
        description="Start tsdb-service on the embedded DuckDB file and feed it Orion notifications "
        "from the lawnmower, warehouse and drone simulators until Ctrl-C or --duration. A bounded run is "
        "live: its simulated time ends when the run ends (a --speedup above 1 replays the recent past and "
        "catches up with the clock), and it starts after whatever an earlier run stored.",
    )
    p.add_argument("--db", default="./data/tsdb.duckdb", help="DuckDB file (default ./data/tsdb.duckdb)")
    p.add_argument("--host", default="127.0.0.1", help="address the demo's service binds (default 127.0.0.1)")
    p.add_argument("--port", type=port, default=8668, help="port of the demo's service (default 8668)")
    p.add_argument("--no-serve", action="store_true", help="do not start a service; feed the one at --url")
    p.add_argument("--url", help="service to feed with --no-serve (default http://localhost:8668)")
    p.add_argument("--speedup", type=positive_number, default=1.0, help="simulated seconds per wall second (default 1)")
    p.add_argument(
        "--duration",
        type=positive_number,
        help="wall seconds to run (default: until Ctrl-C). A run can overrun: when the simulators cannot "
        "keep up with --speedup, every notification is still sent and the run ends late (the progress "
        "display says by how much and when it will end)",
    )
    p.add_argument("--seed", type=integer, help="make the run reproducible (default: a random seed, printed)")
    p.add_argument(
        "--use-case",
        action="append",
        metavar="NAME",
        help=f"only these simulators ({', '.join(USE_CASE_NAMES)}; repeat or comma-separate; default: all three)",
    )
    p.add_argument("--concurrency", type=positive_int, default=16, help="notifications in flight at most (default 16)")
    p.add_argument(
        "--broker",
        metavar="URL",
        help="update the entities in this Orion broker (e.g. http://orion:1026) instead of notifying the service: "
        "the broker notifies the service through the subscriptions `tsdb-service subscribe` made (default: none, "
        "the simulators notify the service directly)",
    )
    _add_ngsi_ld(p, "the broker is Orion-LD: NGSI-LD entity updates (with --broker)")
    p.add_argument(
        "--via",
        choices=("http", "mqtt"),
        default="http",
        help="how notifications reach the service: http (POST /v2/notify) or mqtt (published to an MQTT broker "
        "on tsdb/SERVICE/PATH, as Orion's mqttCustom does, and consumed by the service; with --broker, Orion "
        "publishes them through `tsdb-service subscribe --mqtt` subscriptions) (default http)",
    )
    p.add_argument(
        "--mqtt-url",
        metavar="URL",
        help="with --via mqtt, the MQTT broker (default: a Mosquitto the demo starts on this machine, when one "
        "is installed; needed with --broker or --no-serve, where the service and Orion must reach the same broker)",
    )


def _add_subscribe(sub) -> None:
    p = sub.add_parser("subscribe", help="create a use case's subscription on a real Orion broker, once")
    p.add_argument("--broker", required=True, metavar="URL", help="the broker's base URL, e.g. http://orion:1026")
    p.add_argument("--use-case", required=True, choices=[*USE_CASE_NAMES, "all"], help="whose subscription to create")
    p.add_argument(
        "--notify-url",
        default=None,
        metavar="URL",
        help="where the broker sends notifications; inside docker-compose.yml's network "
        "http://tsdb-service:8668/v2/notify (default: port 8668 of this machine, at the address the broker "
        "reaches it by; printed)",
    )
    _add_ngsi_ld(p, "an NGSI-LD subscription (Orion-LD), notifying /ngsi-ld/v1/notify")
    p.add_argument(
        "--mqtt",
        metavar="URL",
        help="notify over MQTT instead of HTTP: publish to this MQTT broker (e.g. mqtt://mosquitto:1883, as the "
        "broker reaches it) at QoS 1, for the service to consume (serve --mqtt-url); instead of --notify-url "
        "(default: notify over HTTP)",
    )
    p.add_argument(
        "--mqtt-topic",
        default=None,
        metavar="TEMPLATE",
        help="with --mqtt, the topic, with Orion's macros (default tsdb/${service}${servicePath}: the service's "
        "default --mqtt-topic-template); with --ngsi-ld the use case's tenant and service path are filled in here",
    )
    p.add_argument(
        "--force",
        action="store_true",
        help="create the subscription even if the broker has an equivalent one (same notify URL and entities) "
        "for the tenant: by default that one is kept and nothing is created, so running twice never stores "
        "every sample twice",
    )


def _add_ngsi_ld(p, text: str) -> None:
    p.add_argument("--ngsi-ld", action="store_true", help=f"{text} (default: NGSIv2, Orion)")


def _add_queries(sub) -> None:
    p = sub.add_parser("queries", help="the request collection: run it or regenerate queries/")
    actions = p.add_subparsers(dest="queries_action", required=True)
    run = actions.add_parser("run", help="run the collection against a service, a PASS/FAIL line per request")
    run.add_argument("--url", default="http://localhost:8668", help="service base URL (default %(default)s)")
    run.add_argument("--only", help="only requests whose name contains this text (default: all)")
    run.add_argument(
        "--from-date", dest="from_date", help="fromDate of the period queries (ISO-8601; default: the collection's own)"
    )
    run.add_argument(
        "--to-date", dest="to_date", help="toDate of the period queries (ISO-8601; default: the collection's own)"
    )
    build = actions.add_parser("build", help="write the Postman collection and the .http file")
    build.add_argument("--out", default="queries", help="folder (default ./queries)")


def _add_notifications(sub) -> None:
    p = sub.add_parser("notifications", help="the Orion subscriptions and recorded notifications")
    actions = p.add_subparsers(dest="notifications_action", required=True)
    build = actions.add_parser(
        "build", help="write notifications/<use case>/ from the simulators (and the lawnmower's recorded ROS 2 bag)"
    )
    build.add_argument("--out", default="notifications", help="folder (default ./notifications)")


# -- demo


def _check_via(args: argparse.Namespace) -> None:
    """``--via mqtt``: a broker to use, or one the demo can start; ValueError otherwise."""
    if args.via != "mqtt":
        if args.mqtt_url:
            raise ValueError("--mqtt-url needs --via mqtt")
        return
    from tsdb_service.core.config import check_mqtt_url
    from tsdb_service.demo.mosquitto import find_mosquitto

    if args.mqtt_url:
        args.mqtt_url = check_mqtt_url(args.mqtt_url)
        return
    if args.broker or args.no_serve:
        who = "Orion" if args.broker else "the service at --url"
        flag = "--broker" if args.broker else "--no-serve"
        raise ValueError(f"--via mqtt with {flag} needs --mqtt-url: the broker {who} and this demo both reach")
    if find_mosquitto() is None:
        raise ValueError(
            "--via mqtt needs an MQTT broker: give --mqtt-url, or install Mosquitto (Debian: apt-get install "
            "mosquitto) for the demo to start one"
        )


def cmd_demo(args: argparse.Namespace) -> int:
    import httpx

    from tsdb_service.core.config import check_db
    from tsdb_service.demo.serve import LocalService
    from tsdb_service.usecases import registry as usecases

    try:
        simulators = usecases.select(args.use_case)
        check_db(args.db)
        if args.ngsi_ld and not args.broker:
            raise ValueError("--ngsi-ld needs --broker: it says what kind of broker the entities are sent to")
        if args.broker:
            check_http_url(args.broker, "--broker", "http://orion:1026", "--via mqtt --mqtt-url")
        _check_via(args)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    broker = args.broker.rstrip("/") if args.broker else None
    unreachable = _unreachable(broker) if broker else None
    if unreachable:
        print(f"error: cannot reach the broker at {broker}: {unreachable}", file=sys.stderr)
        return 2
    if args.via == "mqtt" and args.mqtt_url and (unreachable := _mqtt_unreachable(args.mqtt_url)):
        print(f"error: cannot reach the MQTT broker at {args.mqtt_url}: {unreachable}", file=sys.stderr)
        return 2
    seed = args.seed if args.seed is not None else random.SystemRandom().randrange(1_000_000)
    service = mosquitto = None
    if args.via == "mqtt" and not args.mqtt_url:
        from tsdb_service.demo.mosquitto import LocalMosquitto

        # Its state next to the demo's file: a second run finds its session and queue again.
        state = Path(args.db).with_suffix(".demo-mosquitto")
        try:
            mosquitto = LocalMosquitto(directory=state).start()
        except RuntimeError as exc:
            first = str(exc).splitlines()[0]
            print(
                f"error: cannot start Mosquitto for --via mqtt ({first}; its log: {state}/mosquitto.log)",
                file=sys.stderr,
            )
            return 2
        args.mqtt_url = mosquitto.url
    if args.no_serve:
        url = (args.url or "http://localhost:8668").rstrip("/")
    else:
        log_path = Path(args.db).with_suffix(".demo-server.log")
        consume = ("--mqtt-url", args.mqtt_url, "--mqtt-client-id", "tsdb-service-demo") if args.via == "mqtt" else ()
        if any(sim.name == "lawnmower" for sim in simulators):
            args.recorded = import_recorded_run(args.db)  # before the service holds the file
        try:
            service = LocalService(args.db, args.host, args.port, log_path, consume).start()
        except BaseException:
            if mosquitto is not None:
                mosquitto.close()
            raise
        url = service.url
    try:
        try:
            start, speedup = _window(simulators, url, args)
        except ValueError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
        except httpx.TransportError as exc:
            print(f"error: cannot reach {url}: {exc}", file=sys.stderr)
            return 2
        _print_banner(args, url, seed, service, start, speedup)
        _print_recorded(getattr(args, "recorded", None), url)
        stats = asyncio.run(_run_demo(simulators, url, args, seed, start, speedup))
        if service is not None and args.via == "mqtt" and not args.broker:
            published = sum(row.acked for row in stats.values())
            consumed = service.wait_consumed(published)  # the broker holds them until then
            if consumed < published:
                print(f"the service has taken {consumed} of the {published} published; the broker keeps the rest")
    finally:
        if service is not None:
            service.stop()
        if mosquitto is not None:
            mosquitto.stop()  # its state stays next to the demo's file
    failed = sum(row.failed for row in stats.values())
    sent = sum(row.sent for row in stats.values())
    print(f"\n{sent} notifications sent, {sent - failed} acknowledged, {failed} failed (seed {seed}).")
    if service is not None:
        print(f"The data stays in {args.db}: `tsdb-service serve --db {args.db}` to explore it again.")
    return 1 if failed else 0


def import_recorded_run(db: str):
    """The lawnmower's recorded run (a ROS 2 bag, ``demo.bag``) into ``db``,
    as ``tsdb-service import rosbag`` does: once, however often the demo
    runs. (folder, report), or None after a warning."""
    from tsdb_service.commands.rosbag.bag import BagError
    from tsdb_service.commands.rosbag.importer import PreparedImport
    from tsdb_service.commands.rosbag.mapping import MapError, load_map
    from tsdb_service.core.config import Settings
    from tsdb_service.demo.bag import BAG_NAME, MAP_NAME, lawnmower_bag
    from tsdb_service.storage import open_store

    if "://" not in db:
        Path(db).parent.mkdir(parents=True, exist_ok=True)
    try:
        folder = lawnmower_bag(db)
        with PreparedImport.open(
            folder / BAG_NAME, load_map(folder / MAP_NAME), f"map {folder / MAP_NAME}"
        ) as prepared:
            store = open_store(Settings(db=db))
            try:
                report = prepared.run(store)
            finally:
                store.close()
    except (BagError, MapError, RuntimeError) as exc:
        print(f"warning: the lawnmower's recorded run was not imported: {exc}", file=sys.stderr)
        return None
    return folder, report


def _print_recorded(recorded, url: str) -> None:
    """Where to see the recorded run: its time range, the MCAP download."""
    if recorded is None:
        return
    from urllib.parse import urlencode

    from tsdb_service.demo.bag import BAG_SECONDS, BAG_START
    from tsdb_service.usecases import sites
    from tsdb_service.usecases.orion import iso

    folder, report = recorded
    end = BAG_START + timedelta(seconds=BAG_SECONDS + 1)
    span = {"fromDate": iso(BAG_START), "toDate": iso(end)}
    tenancy = f"-H 'Fiware-Service: {sites.LAWNMOWER.service}' -H 'Fiware-ServicePath: {sites.LAWNMOWER.service_path}'"
    stored = "imported now" if report.messages else "imported by an earlier run"
    print(f"Recorded run: the lawnmower's ROS 2 bag {folder}/run ({report.total} messages, {stored}):")
    print(f"  in history from {span['fromDate']} to {span['toDate']} (explorer and Grafana: that time range)")
    print(f"  for Foxglove:  curl -s {tenancy} -o run.mcap '{url}/v2/export?{urlencode({**span, 'format': 'mcap'})}'")
    sys.stdout.flush()


def _window(simulators, url: str, args: argparse.Namespace):
    """(simulated start, speedup): live, and after what earlier runs stored."""
    from datetime import UTC, datetime

    from tsdb_service.demo.runner import live_window

    now = datetime.now(UTC)
    return live_window(args.speedup, args.duration, now, previous_end(url, simulators))


def previous_end(url: str, simulators) -> datetime | None:
    """The newest instant stored for these simulators' tenants (an earlier run's end), or None."""
    import httpx

    newest = None
    with httpx.Client(base_url=url, timeout=30.0) as client:
        for sim in simulators:
            headers = {"Fiware-Service": sim.tenancy.service, "Fiware-ServicePath": sim.tenancy.service_path}
            response = client.get("/v2/entities", headers=headers)
            if response.status_code != 200 or not response.json():
                continue
            for entity in response.json():
                at = datetime.fromisoformat(entity["index"].replace("Z", "+00:00"))
                newest = at if newest is None or at > newest else newest
    return newest


async def _run_demo(simulators, url: str, args: argparse.Namespace, seed: int, start, speedup: float):
    from tsdb_service.demo.runner import Progress, RunConfig, run

    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    loop.add_signal_handler(signal.SIGINT, stop.set)  # first Ctrl-C: drain and stop cleanly
    loop.add_signal_handler(signal.SIGTERM, stop.set)
    config = RunConfig(
        url=url,
        speedup=speedup,
        duration=args.duration,
        seed=seed,
        concurrency=args.concurrency,
        start=start,
        broker=args.broker,
        ngsi_ld=args.ngsi_ld,
        mqtt=args.mqtt_url if args.via == "mqtt" else None,
    )
    try:
        return await run(simulators, config, progress=Progress(), stop=stop)
    finally:
        loop.remove_signal_handler(signal.SIGINT)
        loop.remove_signal_handler(signal.SIGTERM)


def _print_banner(args: argparse.Namespace, url: str, seed: int, service, start, speedup: float) -> None:
    from datetime import timedelta

    from tsdb_service.demo.collection import DEMO_EXAMPLES, by_name, curl
    from tsdb_service.usecases.orion import iso

    where = f"(DuckDB file {args.db}; log {service.log_path})" if service else "(already running)"
    until = f"for {args.duration:g} s" if args.duration else "until Ctrl-C"
    if args.broker:
        kind = "Orion-LD (NGSI-LD)" if args.ngsi_ld else "Orion (NGSIv2)"
        print(f"tsdb-service demo: updating the entities in {kind} at {args.broker.rstrip('/')}; it notifies {url}")
        print(
            "  through its subscriptions: `tsdb-service subscribe` creates them"
            + (" (--ngsi-ld)" if args.ngsi_ld else "")
        )
    elif args.via == "mqtt":
        print(f"tsdb-service demo: publishing to the MQTT broker {args.mqtt_url}, consumed by {url} {where}")
    else:
        print(f"tsdb-service demo: feeding {url} {where}")
    print(f"  explorer     {url}/ui  (charts, maps and the three use cases in a browser)")
    print(f"  API docs     {url}/docs")
    print(f"  dashboards   {url}/ui/#/dashboards  (Grafana dashboards: their JSON and how to import them)")
    print(f"  history API  {url}/v2/entities  (headers Fiware-Service / Fiware-ServicePath)")
    print("  requests     queries/tsdb-service.postman_collection.json, queries/tsdb-service.http")
    if service is not None:
        _print_reach(args.host, args.port)
    print("Try:")
    for name in DEMO_EXAMPLES:
        print(f"  # {name}\n  {curl(by_name(name), url)}")
    print(f"Simulating x{speedup:.3g} {until}, seed {seed}:")
    if args.duration:
        end = start + timedelta(seconds=args.duration * speedup)
        print(f"  simulated time {iso(start)} to {iso(end)}: live, it ends when the run does")
        if speedup != args.speedup:
            print(
                f"  (it starts after the data of an earlier run, so it replays at x{speedup:.3g} "
                f"instead of x{args.speedup:g} to still end on time)"
            )
    elif args.speedup > 1:
        print(
            "  (open-ended at a speedup: simulated time starts now and runs ahead of the clock;"
            " give --duration to end the replay at the present instead)"
        )
    sys.stdout.flush()


def _print_reach(host: str, port: int) -> None:
    """Where the demo's service listens, and how another machine reaches it."""
    pad = " " * 15
    if host in ("127.0.0.1", "localhost", "::1"):
        bound = f"[{host}]" if ":" in host else host
        print(f"  listening    {bound}:{port} only, this machine. From another machine, a tunnel:")
        print(f"{pad}ssh -L {port}:{bound}:{port} USER@THIS_HOST, then http://localhost:{port}/ui over there;")
        print(f"{pad}or rerun with --host 0.0.0.0 on a network you trust: the demo has no authentication,")
        print(f"{pad}so whoever reaches port {port} can read, write and delete the history.")
    else:
        print(f"  listening    {host}:{port}, with no authentication: whoever reaches port {port} can read,")
        print(f"{pad}write and delete the history (the default --host 127.0.0.1 keeps it to this machine).")


# -- subscribe


def cmd_subscribe(args: argparse.Namespace) -> int:
    from tsdb_service.broker.subscriptions import (
        MQTT_TOPIC,
        NGSI_LD,
        NGSIV2,
        default_notify_url,
        ensure_subscription,
        mqtt_api,
        topic_of,
    )
    from tsdb_service.core.config import check_mqtt_url
    from tsdb_service.usecases.registry import SIMULATORS

    try:
        # before anything reaches the network; Orion's API is HTTP even when it notifies over MQTT
        check_http_url(args.broker, "--broker", "http://orion:1026", "--mqtt mqtt://HOST:1883")
        if args.notify_url:
            check_http_url(args.notify_url, "--notify-url", "http://tsdb-service:8668/v2/notify", "--mqtt")
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    names = USE_CASE_NAMES if args.use_case == "all" else (args.use_case,)
    if args.mqtt:
        topic = args.mqtt_topic or MQTT_TOPIC
        try:
            if args.notify_url:
                raise ValueError("--mqtt and --notify-url: the broker notifies over one or the other")
            check_mqtt_url(args.mqtt)
            if args.ngsi_ld:
                topic_of(SIMULATORS[names[0]], topic)
        except ValueError as exc:
            print(f"error: --mqtt: {exc}" if "--" not in str(exc) else f"error: {exc}", file=sys.stderr)
            return 2
        api = mqtt_api(args.ngsi_ld, topic)
        notify_url = args.mqtt.rstrip("/")
        print(f"notify over MQTT: {notify_url}, topic {topic} (the service consumes it with --mqtt-url)")
    elif args.mqtt_topic:
        print("error: --mqtt-topic needs --mqtt", file=sys.stderr)
        return 2
    else:
        api = NGSI_LD if args.ngsi_ld else NGSIV2
        notify_url = args.notify_url or default_notify_url(args.broker, path=api.notify_path)
        given = "" if args.notify_url else " (this machine as the broker reaches it; --notify-url to choose)"
        print(f"notify URL: {notify_url}{given}")
    all_ok = True
    for name in names:
        ok, answer = ensure_subscription(args.broker, SIMULATORS[name], notify_url, force=args.force, api=api)
        print(f"{name}: {answer}{_published_on(SIMULATORS[name], topic) if args.mqtt else ''}")
        all_ok &= ok
    return 0 if all_ok else 1


def check_http_url(url: str, flag: str, example: str, mqtt_flag: str) -> None:
    """``url`` is ``http(s)://HOST[:PORT][/PATH]``; else ValueError, one line
    naming ``flag``. An MQTT URL is pointed to ``mqtt_flag``, where MQTT goes."""
    from urllib.parse import urlsplit

    parts = urlsplit(url.strip())
    scheme = parts.scheme.lower()
    if scheme in ("http", "https") and parts.hostname:
        return
    mqtt = f" (MQTT goes in {mqtt_flag})" if scheme in ("mqtt", "mqtts") else ""
    raise ValueError(f"{flag} {url[:80]!r} is not an http:// or https:// URL: give one like {example}{mqtt}")


def _published_on(sim, topic: str) -> str:
    """Where the broker will publish the use case's notifications (for the
    operator to match with the service's topics), when the macros say."""
    from tsdb_service.broker.subscriptions import topic_of

    try:
        return f"; published on topic {topic_of(sim, topic)}"
    except ValueError:  # another Orion macro (${id}, ...): known only per notification
        return ""


# -- queries


def cmd_queries(args: argparse.Namespace) -> int:
    if args.queries_action == "build":
        return _queries_build(Path(args.out))
    return _queries_run(args)


def _queries_build(out: Path) -> int:
    for path in write_collection(out):
        print(f"wrote {path}")
    return 0


def write_collection(out: Path) -> list[Path]:
    """Write both exports of the collection into ``out``."""
    from tsdb_service.broker.subscriptions import dumps
    from tsdb_service.demo.collection import http_file, postman_collection

    out.mkdir(parents=True, exist_ok=True)
    postman = out / "tsdb-service.postman_collection.json"
    postman.write_bytes(dumps(postman_collection()))
    http = out / "tsdb-service.http"
    http.write_text(http_file())
    return [postman, http]


def _queries_run(args: argparse.Namespace) -> int:
    from tsdb_service.demo.collection import matching, run_all

    queries = matching(args.only)
    if not queries:
        print(f"no request name contains {args.only!r}", file=sys.stderr)
        return 2
    url = args.url.rstrip("/")
    unreachable = _unreachable(url)
    if unreachable:
        print(f"error: cannot reach {url}: {unreachable}", file=sys.stderr)
        return 2
    variables = {k: v for k, v in (("fromDate", args.from_date), ("toDate", args.to_date)) if v}
    outcomes = run_all(url, queries, variables)
    for outcome in outcomes:
        verdict = "PASS" if outcome.ok else "FAIL"
        detail = "" if outcome.ok else f": {outcome.detail}"
        print(f"{verdict}  {outcome.query.name}  ({outcome.elapsed_ms:.0f} ms){detail}")
    failed = sum(not o.ok for o in outcomes)
    print(f"{len(outcomes) - failed} of {len(outcomes)} requests passed")
    return 1 if failed else 0


def _mqtt_unreachable(url: str) -> str | None:
    """Why nothing accepts a connection at the MQTT broker ``url``, or None:
    checked first, so the demo says so in one line instead of failing later."""
    import socket
    from urllib.parse import urlsplit

    from tsdb_service.core.config import MQTT_SCHEMES

    parts = urlsplit(url)
    try:
        socket.create_connection((parts.hostname, parts.port or MQTT_SCHEMES[parts.scheme]), timeout=5).close()
    except OSError as exc:
        return str(exc) or type(exc).__name__
    return None


def _unreachable(url: str) -> str | None:
    """Why the service at ``url`` cannot be reached, or None: checked once up
    front, so a wrong URL is one line rather than the same failure per request."""
    import httpx

    try:
        httpx.get(f"{url}/version", timeout=10.0)
    except httpx.TransportError as exc:
        return str(exc) or type(exc).__name__
    return None


# -- notifications


def cmd_notifications(args: argparse.Namespace) -> int:
    from tsdb_service.broker.subscriptions import write_examples
    from tsdb_service.demo.bag import write_lawnmower_bag

    for path in [*write_examples(Path(args.out)), *write_lawnmower_bag(Path(args.out) / "lawnmower")]:
        print(f"wrote {path}")
    return 0
