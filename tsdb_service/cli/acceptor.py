"""An acceptor process of ``serve --ingest-processes`` (``ingest.acceptor``):
started by the serving process (``ingest.processes``), never by hand. It
reads the settings from the ``TSDB_*`` variables ``serve`` set, accepts
from the listening socket the serving process gave it (one of the port's,
``http.server.listening_sockets``) and stops when the serving process goes."""

from __future__ import annotations

import os
import shutil
import socket
import sys


def main() -> int:
    import uvicorn

    from tsdb_service.app import create_acceptor_app
    from tsdb_service.cli.main import tune_collector
    from tsdb_service.core.config import Settings
    from tsdb_service.http.handoff import HandOver, handing_over
    from tsdb_service.http.server import log_config, raise_fd_limit
    from tsdb_service.ingest.http_notify import NOTIFY_PATHS
    from tsdb_service.ingest.processes import HANDOVER_SOCKET, LISTEN_FDS_VARIABLE, RELAY_DIR_VARIABLE

    relay_dir = os.environ.get(RELAY_DIR_VARIABLE)
    listen_fd = os.environ.get(LISTEN_FDS_VARIABLE)
    if not relay_dir or not listen_fd:
        print("error: an ingest process is started by 'tsdb-service serve --ingest-processes N'", file=sys.stderr)
        return 2
    settings = Settings()
    raise_fd_limit()
    app = create_acceptor_app(settings, relay_dir)
    config = uvicorn.Config(
        app,
        lifespan="on",
        log_level=settings.log_level,
        log_config=log_config(settings.log_level),
        access_log=settings.access_log,
        loop="uvloop",
        # Notifications served here; any other request's connection goes to the owner (http.handoff).
        http=handing_over(frozenset(p.encode() for p in NOTIFY_PATHS), HandOver(f"{relay_dir}/{HANDOVER_SOCKET}")),
        timeout_keep_alive=settings.keep_alive_s,
        timeout_graceful_shutdown=30,
    )
    server = uvicorn.Server(config)

    lost = []

    def owner_lost() -> None:  # what it holds can no longer be written: answer it 503 and go at once
        lost.append(True)
        server.should_exit = server.force_exit = True

    app.on_owner_lost = owner_lost
    tune_collector()
    server.run(sockets=[socket.socket(fileno=int(listen_fd))])  # its own socket on the port, from the serving process
    if lost:  # a serving process that was killed could not remove its run's directory
        shutil.rmtree(relay_dir, ignore_errors=True)
    return 0 if server.started else 3


if __name__ == "__main__":
    sys.exit(main())
