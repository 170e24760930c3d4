"""``tsdb-service``: serve, migrate, compact, version (and more, per command)."""

from __future__ import annotations

import argparse
import gc
import os
import sys
from collections.abc import Callable, Sequence
from types import ModuleType
from typing import Any, NoReturn

from tsdb_service import __version__
from tsdb_service.cli.messages import readable
from tsdb_service.cli.newdb import new_duckdb_file
from tsdb_service.cli.parser import CommandParser, Formatter
from tsdb_service.cli.settingflags import setting_help, setting_metavar
from tsdb_service.core.config import (
    LOG_LEVELS,
    Settings,
    SettingsError,
    flag_named,
    load_settings,
    setting_groups,
)

Command = Callable[[argparse.Namespace], int]
COMMANDS: dict[str, Command] = {}


def command(name: str):
    def register(fn: Command) -> Command:
        COMMANDS[name] = fn
        return fn

    return register


def _settings(args: argparse.Namespace) -> Settings:
    """Flags over ``TSDB_*`` variables over defaults; ``SettingsError`` (one line) if any is invalid."""
    overrides = {k: v for k, v in vars(args).items() if k in Settings.model_fields and v is not None}
    return load_settings(**overrides)


def _add_db(p: argparse.ArgumentParser | argparse._ArgumentGroup) -> None:
    p.add_argument("--db", metavar="PATH|URL", help=setting_help("db"))


def _add_settings(p: argparse.ArgumentParser) -> None:
    """One flag per setting, e.g. ``--max-body-bytes``, under its group's
    heading: every setting can be given as a flag or a ``TSDB_*`` variable,
    and validation names both."""
    for group, names in setting_groups():
        section = p.add_argument_group(group.title, group.about)
        for name in names:
            _add_setting(section, name)


def _add_setting(section: argparse._ArgumentGroup, name: str) -> None:
    field = Settings.model_fields[name]
    flag = "--" + name.replace("_", "-")
    if field.annotation not in _SCALARS:
        return  # structured settings (if any) are variables only
    if name == "db":
        _add_db(section)
    elif field.annotation is bool:
        # a setting on by default needs its --no- form to be turned off by a flag
        action = argparse.BooleanOptionalAction if field.default is True else "store_true"
        section.add_argument(flag, dest=name, action=action, default=None, help=setting_help(name))
    elif name == "log_level":
        section.add_argument(flag, dest=name, metavar="{" + ",".join(LOG_LEVELS) + "}", help=setting_help(name))
    else:
        section.add_argument(flag, dest=name, metavar=setting_metavar(name), help=setting_help(name))


_SCALARS = (str, int, float, bool, int | None, float | None, str | None)


def build_parser() -> argparse.ArgumentParser:
    parser = CommandParser(
        prog="tsdb-service", description="The history of a FIWARE deployment.", formatter_class=Formatter
    )
    parser.add_argument("--version", action="version", version=f"tsdb-service {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    serve = sub.add_parser(
        "serve",
        help="run the HTTP service",
        formatter_class=Formatter,
        description="Run the HTTP service. Every flag can also be given as the TSDB_* "
        "variable named in its help; flags win.",
    )
    _add_settings(serve)

    migrate = sub.add_parser("migrate", help="apply pending schema migrations", formatter_class=Formatter)
    _add_db(migrate)

    compact = sub.add_parser(
        "compact", help="sort all stored samples now (offline; the file must exist)", formatter_class=Formatter
    )
    _add_db(compact)

    sub.add_parser("version", help="print the version")
    for module in _feature_modules():
        module.register(sub, command)
    return parser


def _feature_modules() -> tuple[ModuleType, ...]:
    """The packages that add their own subcommands, each through
    ``register(subparsers, command)``; imported when the parser is built, so
    ``import tsdb_service.cli.main`` stays light."""
    from tsdb_service.cli import backup as backup_commands
    from tsdb_service.cli import copy as copy_commands
    from tsdb_service.cli import dashboards as grafana_commands
    from tsdb_service.cli import demo as demo_commands
    from tsdb_service.cli import export as export_commands
    from tsdb_service.cli import qlimport as import_commands
    from tsdb_service.cli import register as register_commands
    from tsdb_service.cli import replay as replay_commands
    from tsdb_service.cli import rollups as rollup_commands
    from tsdb_service.cli import rosbag as rosbag_commands

    return (
        demo_commands,
        grafana_commands,
        copy_commands,
        export_commands,
        import_commands,
        rosbag_commands,  # after import_commands: a source of `import`
        replay_commands,
        backup_commands,
        register_commands,
        rollup_commands,
    )


@command("serve")
def cmd_serve(args: argparse.Namespace) -> int:
    import uvicorn

    from tsdb_service.storage import check_store

    settings = _settings(args)
    if settings.workers > 1 and settings.backend == "duckdb":
        print(
            "error: --workers > 1 needs PostgreSQL. An embedded DuckDB file belongs to one process; "
            "use --db postgresql://... to run several workers.",
            file=sys.stderr,
        )
        return 2
    if settings.workers > 1 and settings.mqtt_url:
        print(
            "error: --mqtt-url with --workers > 1: each worker would be its own MQTT client, and a session "
            "needs a client id of its own that stays the same across restarts. Run one worker per replica "
            "(each with its --mqtt-client-id, on one --mqtt-share-group) instead.",
            file=sys.stderr,
        )
        return 2
    if settings.ingest_processes > 1 and settings.backend != "duckdb":
        print(
            "error: --ingest-processes > 1 is for DuckDB, whose file belongs to one process; with PostgreSQL "
            "use --workers, whose processes each write to the database.",
            file=sys.stderr,
        )
        return 2
    check_serve(settings)  # one line each, before anything is created
    created = new_duckdb_file(settings)
    check_store(settings)  # a wrong --db is one line here, before uvicorn starts
    if created is not None:
        import logging
        import logging.config

        from tsdb_service.http.server import log_config

        logging.config.dictConfig(log_config(settings.log_level))  # uvicorn's format; uvicorn.run sets it again
        logging.getLogger(__name__).info("created a new, empty DuckDB database at %s", created)
    # Workers are separate processes: hand them the settings through the environment.
    for name, value in settings.model_dump().items():
        if value is not None:  # unset: the backend's default applies
            os.environ[f"TSDB_{name.upper()}"] = str(value)
    # --- limits (issue 12): slow clients, connection cap, descriptors (tsdb_service.http.server) ---
    from tsdb_service.http.server import GuardedHttpToolsProtocol, log_config, raise_fd_limit

    raise_fd_limit()
    options: dict[str, Any] = {
        "log_level": settings.log_level,
        "log_config": log_config(settings.log_level),  # tsdb-service's own lines too (the database opened)
        "access_log": settings.access_log,
        "loop": "uvloop",
        "http": GuardedHttpToolsProtocol,  # httptools with header/body deadlines and a connection cap
        "timeout_keep_alive": settings.keep_alive_s,
        "timeout_graceful_shutdown": 30,
    }
    # --- end of limits ---
    if settings.ingest_processes > 1:
        return serve_with_acceptors(settings, options)
    uvicorn.run(
        "tsdb_service.cli.main:serve_app",
        factory=True,
        host=settings.host,
        port=settings.port,
        workers=settings.workers,
        **options,
    )
    return 0


def serve_with_acceptors(settings: Settings, options: dict[str, Any]) -> int:
    """``serve --ingest-processes N``: this process owns the database and
    serves everything, on the port it shares with N-1 acceptor processes
    (started by the app's lifespan, ``ingest.processes``), on a private Unix
    socket for the requests they pass on (``ingest.acceptor``), and the
    connections they hand over (``http.handoff``)."""
    import shutil
    import tempfile
    from pathlib import Path

    import uvicorn

    from tsdb_service.http.server import listening_sockets, private_socket
    from tsdb_service.ingest.processes import (
        HANDOVER_SOCKET,
        LISTEN_FDS_VARIABLE,
        OWNER_HTTP_SOCKET,
        RELAY_DIR_VARIABLE,
    )

    relay_dir = tempfile.mkdtemp(prefix="tsdb-ingest-")  # 0700: this user only
    os.environ[RELAY_DIR_VARIABLE] = relay_dir
    try:
        public, *theirs = listening_sockets(settings.host, settings.port, settings.ingest_processes)
        os.environ[LISTEN_FDS_VARIABLE] = ",".join(str(s.fileno()) for s in theirs)  # handed to the acceptors
        sockets = [public, private_socket(str(Path(relay_dir) / OWNER_HTTP_SOCKET))]
        config = uvicorn.Config("tsdb_service.cli.main:serve_app", factory=True, **options)
        server = owner_server(config, str(Path(relay_dir) / HANDOVER_SOCKET))
        print(
            f"tsdb-service listens on http://{settings.host}:{settings.port} with {settings.ingest_processes} "
            "ingest processes",
            file=sys.stderr,
        )
        server.run(sockets=sockets)
    finally:
        shutil.rmtree(relay_dir, ignore_errors=True)
    return 0 if server.started else 3


def owner_server(config, handover_path: str):
    """uvicorn's server, also serving the connections acceptors hand over
    (``http.handoff``) once the app has started, with the same protocol."""
    from functools import partial
    from typing import cast

    import uvicorn

    from tsdb_service.http.handoff import Adopter

    class OwnerServer(uvicorn.Server):
        adopter: Adopter | None = None

        async def startup(self, sockets=None) -> None:
            await super().startup(sockets)
            make = partial(
                cast(Any, self.config.http_protocol_class),
                config=self.config,
                server_state=self.server_state,
                app_state=self.lifespan.state,
            )
            self.adopter = Adopter(handover_path, make)
            self.adopter.start()

        async def shutdown(self, sockets=None) -> None:
            if self.adopter is not None:
                self.adopter.close()
            await super().shutdown(sockets)

    return OwnerServer(config)


WRITER_SWITCH_INTERVAL_S = 0.0002


def tune_interpreter() -> None:
    """Process-wide, so the ``serve`` process's alone (never ``create_app``,
    which tests and embedders call): the writer thread needs the GIL back
    after each database call, and with the default 5 ms switch interval a
    busy event loop makes every group commit wait that long, which caps
    ingest far below what DuckDB does."""
    sys.setswitchinterval(WRITER_SWITCH_INTERVAL_S)


def tune_collector() -> None:
    """Once the store is open: ingest allocates many short-lived objects, so
    move everything built at start-up out of the collector's way and collect
    young objects less often."""
    gc.freeze()
    gc.set_threshold(50_000, 20, 20)


def check_serve(settings: Settings) -> None:
    """What ``serve`` can check before it creates the database or starts
    uvicorn: that it can listen on ``--host``/``--port``, and the security
    and NGSI-LD settings that are read at start (keys, key file, token
    settings, local @context files). ``SettingsError``, one line."""
    from tsdb_service import security
    from tsdb_service.faces.ngsild.context import check_local_contexts
    from tsdb_service.http.server import check_bind
    from tsdb_service.ingest.mqtt.config import MqttConfig

    try:
        security.check(settings)  # keys, tokens, a weak secret, an open CORS
        check_local_contexts(settings.ngsild_contexts)
        MqttConfig.from_settings(settings)  # topics, templates, credentials, TLS files
        check_bind(settings.host, settings.port)
    except ValueError as exc:
        raise SettingsError(flag_named(str(exc))) from None


def serve_app():
    """uvicorn's factory for ``serve``: the app, with a start-up failure that
    an operator can fix reported as one line instead of a traceback.

    uvicorn logs whatever message the lifespan's failure carries (Starlette
    puts the whole traceback there) and then exits with status 3. The store
    has already explained its failure in one line (``StoreUnavailable``), so
    that line replaces the traceback. Only the lifespan is wrapped: requests
    do not pass through here.
    """
    from tsdb_service.app import create_app_from_env
    from tsdb_service.storage import StoreUnavailable

    tune_interpreter()
    app = create_app_from_env()
    lifespan = app.router.lifespan

    async def one_line_lifespan(scope, receive, send):
        async def send_short(message):
            failure = sys.exc_info()[1]
            if message["type"] == "lifespan.startup.failed" and isinstance(failure, StoreUnavailable | SettingsError):
                message = {**message, "message": f"error: {readable(str(failure))}"}
            elif message["type"] == "lifespan.startup.complete":
                tune_collector()
            await send(message)

        await lifespan(scope, receive, send_short)

    # Replaced on this router only, so requests pass no wrapper; Starlette types
    # ``Router.lifespan`` as a method, not as the ASGI callable it is used as.
    app.router.lifespan = one_line_lifespan  # type: ignore[method-assign]
    return app


@command("migrate")
def cmd_migrate(args: argparse.Namespace) -> int:
    from tsdb_service.storage import check_store, migrate

    settings = _settings(args)
    created = new_duckdb_file(settings)
    check_store(settings)
    if created is not None:
        print(f"created a new, empty DuckDB database at {created}")
    applied = migrate(settings)
    print(f"applied migrations: {applied}" if applied else "schema is up to date")
    return 0


@command("compact")
def cmd_compact(args: argparse.Namespace) -> int:
    from tsdb_service.storage import open_store, require_history

    settings = _settings(args)
    require_history(settings.db)  # a mistyped path must not become a new, empty database
    store = open_store(settings)
    try:
        done = store.compact(full=True)
    finally:
        store.close()
    print(done)
    return 0


@command("version")
def cmd_version(_: argparse.Namespace) -> int:
    print(__version__)
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args, unknown = parser.parse_known_args(argv)
    if unknown:  # said by the subcommand that was given them, with its usage
        _refuse_unknown(_chosen_parser(parser, args), unknown)
    try:
        return COMMANDS[args.command](args)
    except (RuntimeError, SettingsError) as exc:  # operator errors: a bad setting, a locked DuckDB file
        print(f"error: {readable(str(exc))}", file=sys.stderr)
        return 2


def _chosen_parser(parser: argparse.ArgumentParser, args: argparse.Namespace) -> argparse.ArgumentParser:
    """The innermost (sub)command parser the command line chose (``queries run``, ``serve``, ...)."""
    while True:
        subparsers = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
        name = getattr(args, subparsers[0].dest, None) if subparsers else None
        if name is None:
            return parser
        parser = subparsers[0].choices[name]


def _refuse_unknown(parser: argparse.ArgumentParser, unknown: list[str]) -> NoReturn:
    """The subcommand's own error for arguments it does not know: one usage
    line, then ``error: ...`` with the flag meant when one is close, exit 2."""
    parser.error(f"unrecognized arguments: {' '.join(unknown)}")


if __name__ == "__main__":
    sys.exit(main())
