"""``tsdb-service``: serve, migrate, compact, version (and more, per command)."""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Callable, Sequence

from . import __version__
from .config import Settings

Command = Callable[[argparse.Namespace], int]
COMMANDS: dict[str, Command] = {}


def command(name: str):
    def register(fn: Command) -> Command:
        COMMANDS[name] = fn
        return fn

    return register


def _settings(args: argparse.Namespace) -> Settings:
    overrides = {k: v for k, v in vars(args).items() if k in Settings.model_fields and v is not None}
    return Settings(**overrides)


def _add_db(p: argparse.ArgumentParser) -> None:
    p.add_argument("--db", help="DuckDB file or postgresql:// URL (env TSDB_DB; default ./data/tsdb.duckdb)")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="tsdb-service", description="The history of a FIWARE deployment.")
    sub = parser.add_subparsers(dest="command", required=True)

    serve = sub.add_parser("serve", help="run the HTTP service")
    _add_db(serve)
    serve.add_argument("--host", help="address to bind (default 0.0.0.0)")
    serve.add_argument("--port", type=int, help="port (default 8668, QuantumLeap's)")
    serve.add_argument("--workers", type=int, help="uvicorn workers (PostgreSQL only)")
    serve.add_argument("--log-level", dest="log_level")
    serve.add_argument("--access-log", dest="access_log", action="store_true", default=None)

    migrate = sub.add_parser("migrate", help="apply pending schema migrations")
    _add_db(migrate)

    compact = sub.add_parser("compact", help="sort all stored samples now (offline)")
    _add_db(compact)

    sub.add_parser("version", help="print the version")
    for module in _feature_modules():
        module.register(sub, command)
    return parser


# Feature packages add their own subcommands: each module named here has
# ``register(subparsers, command)``; it is imported only when it exists, so a
# feature can land without touching this file again.
FEATURE_COMMANDS = (
    "tsdb_service.demo.commands",
    "tsdb_service.grafana.commands",
    "tsdb_service.storage.copy",
    "tsdb_service.export.commands",
)


def _feature_modules():
    import importlib

    for name in FEATURE_COMMANDS:
        try:
            module = importlib.import_module(name)
        except ModuleNotFoundError as exc:
            if exc.name and name.startswith(exc.name):
                continue  # that feature is not installed in this tree
            raise
        yield module


@command("serve")
def cmd_serve(args: argparse.Namespace) -> int:
    import uvicorn

    settings = _settings(args)
    if settings.workers > 1 and settings.backend == "duckdb":
        print(
            "error: --workers > 1 needs PostgreSQL. An embedded DuckDB file belongs to one process; "
            "use --db postgresql://... to run several workers.",
            file=sys.stderr,
        )
        return 2
    # Workers are separate processes: hand them the settings through the environment.
    for name, value in settings.model_dump().items():
        if value is not None:  # unset: the backend's default applies
            os.environ[f"TSDB_{name.upper()}"] = str(value)
    # --- limits (issue 12): slow clients, connection cap, descriptors (tsdb_service.httpserver) ---
    from .httpserver import GuardedHttpToolsProtocol, raise_fd_limit

    raise_fd_limit()
    uvicorn.run(
        "tsdb_service.app:create_app_from_env",
        factory=True,
        host=settings.host,
        port=settings.port,
        workers=settings.workers,
        log_level=settings.log_level,
        access_log=settings.access_log,
        loop="uvloop",
        http=GuardedHttpToolsProtocol,  # httptools with header/body deadlines and a connection cap
        timeout_keep_alive=settings.keep_alive_s,
        timeout_graceful_shutdown=30,
    )
    # --- end of limits ---
    return 0


@command("migrate")
def cmd_migrate(args: argparse.Namespace) -> int:
    settings = _settings(args)
    if settings.backend == "postgresql":
        from .storage.postgres_store import migrate_url

        applied = migrate_url(settings.db)
    else:
        from .storage.duckdb_store import connect, migrate_duckdb

        con = connect(settings.db)
        try:
            applied = migrate_duckdb(con)
        finally:
            con.close()
    print(f"applied migrations: {applied}" if applied else "schema is up to date")
    return 0


@command("compact")
def cmd_compact(args: argparse.Namespace) -> int:
    from .storage import open_store

    store = open_store(_settings(args))
    try:
        if hasattr(store, "compact"):
            store.compact(full=True)
    finally:
        store.close()
    print("compacted")
    return 0


@command("version")
def cmd_version(_: argparse.Namespace) -> int:
    print(__version__)
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return COMMANDS[args.command](args)
    except RuntimeError as exc:  # operator errors, e.g. a locked DuckDB file
        print(f"error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
