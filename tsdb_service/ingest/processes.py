"""The serving process's acceptor processes (``--ingest-processes``; ``ingest.relay``).

Invariants:

* **Started after the relay listens, stopped before it closes.** The
  owner's lifespan starts them once the store is open and the relay socket
  takes frames, and stops them (SIGTERM: each finishes the requests it
  holds, whose writes still reach the owner) before the relay and the store
  close.
* **An acceptor that dies is started again**, after a pause that doubles
  with each death in a row (at most ``MAX_PAUSE_S``), and the death is
  logged with its exit status; ``alive`` and ``restarts`` say how they
  fare (``/health``, ``/metrics``).
* **They inherit the settings** through the ``TSDB_*`` variables ``serve``
  sets, the relay's directory through ``RELAY_DIR_VARIABLE``, and their
  listening socket itself (``LISTEN_FDS_VARIABLE``; ``serve`` bound one per
  process, ``http.server.listening_sockets``): a new acceptor takes over
  the socket of the one it replaces, and the connections waiting in it.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import signal
import sys
from collections.abc import Callable

log = logging.getLogger(__name__)

RELAY_DIR_VARIABLE = "TSDB_INTERNAL_RELAY_DIR"
LISTEN_FDS_VARIABLE = "TSDB_INTERNAL_LISTEN_FDS"  # the acceptors' HTTP listening sockets, one each
RELAY_SOCKET = "relay.sock"  # frames (ingest.relay)
OWNER_HTTP_SOCKET = "http.sock"  # the owner's HTTP, for requests an acceptor passes on
HANDOVER_SOCKET = "handover.sock"  # connections an acceptor hands to the owner (http.handoff)
FIRST_PAUSE_S = 0.5
MAX_PAUSE_S = 10.0
STOP_TIMEOUT_S = 30.0
STEADY_S = 60.0


class Acceptors:
    """One acceptor process per listening socket in ``listen_fds``, kept running until ``stop``."""

    def __init__(self, relay_dir: str, listen_fds: list[int], relayed: Callable[[], int] = lambda: 0):
        self.count = len(listen_fds)
        self.relay_dir = relay_dir
        self.listen_fds = listen_fds
        self._relayed = relayed
        self.restarts = 0
        self._processes: dict[int, asyncio.subprocess.Process] = {}
        self._watchers: list[asyncio.Task] = []
        self._stopping = False

    @property
    def alive(self) -> int:
        return sum(1 for p in self._processes.values() if p.returncode is None)

    def snapshot(self) -> dict[str, int]:
        """For ``/metrics``: running, restarted, writes relayed."""
        return {"alive": self.alive, "restarts": self.restarts, "relayed": self._relayed()}

    def health(self) -> str | None:
        """Why ``/health`` warns: an acceptor is not running (the others,
        and this process, take its share of new connections meanwhile)."""
        missing = self.count - self.alive
        if missing <= 0 or self._stopping:
            return None
        return (
            f"{missing} of {self.count} ingest processes not running (started again {self.restarts} times so far); "
            "the others take their connections"
        )

    async def start(self) -> None:
        for slot in range(self.count):
            await self._spawn(slot)
            self._watchers.append(asyncio.get_running_loop().create_task(self._keep(slot)))

    async def _spawn(self, slot: int) -> None:
        fd = self.listen_fds[slot]
        env = {**os.environ, RELAY_DIR_VARIABLE: self.relay_dir, LISTEN_FDS_VARIABLE: str(fd)}
        process = await asyncio.create_subprocess_exec(
            sys.executable,
            "-m",
            "tsdb_service.cli.acceptor",
            env=env,
            stdin=asyncio.subprocess.DEVNULL,
            pass_fds=(fd,),
        )
        self._processes[slot] = process
        log.info("ingest process %d started (pid %d)", slot + 1, process.pid)

    async def _keep(self, slot: int) -> None:
        pause = FIRST_PAUSE_S
        loop = asyncio.get_running_loop()
        while True:
            process = self._processes[slot]
            started = loop.time()
            status = await process.wait()
            if loop.time() - started > STEADY_S:
                pause = FIRST_PAUSE_S  # it had run well: not a death in a row
            if self._stopping:
                return
            log.error(
                "ingest process %d (pid %d) exited with status %s; starting it again in %.1f s",
                slot + 1,
                process.pid,
                status,
                pause,
            )
            await asyncio.sleep(pause)
            if self._stopping:
                return
            self.restarts += 1
            await self._spawn(slot)
            pause = min(pause * 2, MAX_PAUSE_S)

    async def stop(self) -> None:
        """SIGTERM each, wait for them (SIGKILL past ``STOP_TIMEOUT_S``)."""
        self._stopping = True
        for task in self._watchers:
            task.cancel()
        running = [p for p in self._processes.values() if p.returncode is None]
        for process in running:
            with contextlib.suppress(ProcessLookupError):
                process.send_signal(signal.SIGTERM)
        if not running:
            return
        _, late = await asyncio.wait([asyncio.ensure_future(p.wait()) for p in running], timeout=STOP_TIMEOUT_S)
        for process in running:
            if process.returncode is None:
                log.error("ingest process pid %d did not stop in %.0f s: killed", process.pid, STOP_TIMEOUT_S)
                with contextlib.suppress(ProcessLookupError):
                    process.kill()
        if late:
            await asyncio.wait(late, timeout=5)
