"""What every benchmark needs, written once.

Paths (the repository root on ``sys.path``, so ``tsdb_service`` imports from
the tree), free localhost ports, a server under test as a subprocess (started,
waited for until its health answer, measured for CPU and memory over its whole
process tree, stopped), load averages, the machine's description, median and
spread over repetitions, percentiles, aligned tables and JSON results.
Benchmarks import it as ``import common`` (``benchmarks/`` is the script's
directory, so it is on ``sys.path`` already).
"""

from __future__ import annotations

import json
import math
import os
import platform
import signal
import socket
import statistics
import subprocess
import sys
import time
import urllib.error
import urllib.request
from collections.abc import Callable, Iterable
from contextlib import suppress
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
HOST = "127.0.0.1"
for _path in (HERE, ROOT):
    if str(_path) not in sys.path:
        sys.path.insert(0, str(_path))

try:
    import psutil
except ImportError:  # pragma: no cover - only for the CPU / memory figures
    psutil = None


# --- ports, processes, environment ----------------------------------------------------------


def fresh_database(backend: str, name: str, workdir: Path):
    """``(db, cluster)``: a new DuckDB file ``workdir/NAME.duckdb`` (cluster
    None), or a fresh database ``name`` of a private PostgreSQL cluster
    started here (``pgutil.BenchCluster``; the caller stops it)."""
    if backend != "postgresql":
        return str(workdir / f"{name}.duckdb"), None
    from pgutil import BenchCluster

    cluster = BenchCluster(name).start()
    return cluster.url, cluster


def free_port() -> int:
    """A port free on 127.0.0.1 now (the server binds it a moment later)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind((HOST, 0))
        return s.getsockname()[1]


def server_env(extra: dict[str, str] | Iterable[str] = (), keep_tsdb: bool = False) -> dict[str, str]:
    """The environment of a server under test: ours, unbuffered, plus ``extra``
    (a dict, or ``KEY=VALUE`` strings). Without ``keep_tsdb`` the caller's
    ``TSDB_*`` settings are dropped, so that only what the benchmark sets counts."""
    env = {k: v for k, v in os.environ.items() if keep_tsdb or not k.startswith("TSDB_")}
    env["PYTHONUNBUFFERED"] = "1"
    items = extra.items() if isinstance(extra, dict) else (item.split("=", 1) for item in extra)
    env.update({key: value for key, value in items})
    return env


def ours_cmd(db: str | Path, port: int, workers: int = 1, ingest_processes: int = 1) -> list[str]:
    """``tsdb-service serve`` on ``db`` (a DuckDB path or a PostgreSQL URL)."""
    cmd = [sys.executable, "-m", "tsdb_service", "serve", "--db", str(db), "--host", HOST, "--port", str(port)]
    cmd += ["--workers", str(workers)] if workers > 1 else []
    return cmd + (["--ingest-processes", str(ingest_processes)] if ingest_processes > 1 else [])


UVICORN_FLAGS = ["--loop", "uvloop", "--http", "httptools", "--no-access-log", "--workers", "1"]


def bare_cmd(port: int) -> list[str]:
    """The bare FastAPI ceiling (``bare_app.py``), served as ours is."""
    app = ["-m", "uvicorn", "--app-dir", str(HERE), "bare_app:app", "--host", HOST, "--port", str(port)]
    return [sys.executable, *app, "--log-level", "warning", *UVICORN_FLAGS]


def raw_cmd(port: int) -> list[str]:
    """The raw ASGI ceiling (``bare_app.raw_app``: no framework), under uvicorn."""
    app = ["-m", "uvicorn", "--app-dir", str(HERE), "bare_app:raw_app", "--host", HOST, "--port", str(port)]
    return [sys.executable, *app, "--log-level", "warning", *UVICORN_FLAGS]


def granian_cmd(target: str, port: int, factory: bool = False, app_dir: Path | None = None) -> list[str]:
    """``target`` (module:attribute) served by granian instead of uvicorn:
    one worker, uvloop, HTTP/1.1, as our uvicorn settings."""
    cmd = [sys.executable, "-m", "granian", "--interface", "asgi", "--host", HOST, "--port", str(port)]
    cmd += ["--workers", "1", "--loop", "uvloop", "--http", "1", "--no-ws", "--log-level", "warning"]
    if app_dir is not None:
        cmd += ["--working-dir", str(app_dir)]
    return cmd + (["--factory"] if factory else []) + [target]


def spawned(name: str, cmd: list[str], port: int, workdir: Path, env: dict[str, str] | None = None) -> Server:
    """A server of ours or the bare app, not started yet: its log ``<name>.log`` in
    ``workdir``, ``env`` on top of ours, ready on any non-5xx answer of /health."""
    return Server(name, cmd, port, workdir / f"{name}.log", server_env(env or {}), "/health", accept_any_answer)


def process_tree(pid: int) -> list:
    """``pid`` and its children (uvicorn workers, the PostgreSQL backends): psutil processes."""
    if psutil is None:
        return []
    try:
        main = psutil.Process(pid)
        return [main, *main.children(recursive=True)]
    except psutil.Error:
        return []


def cpu_seconds(processes: list) -> float:
    """User + system CPU of ``processes`` so far (NaN without psutil)."""
    if not processes:
        return math.nan
    total = 0.0
    for p in processes:
        with suppress(psutil.Error):
            total += sum(p.cpu_times()[:2])
    return total


def rss_bytes(processes: list) -> int | None:
    if not processes:
        return None
    total = 0
    for p in processes:
        with suppress(psutil.Error):
            total += p.memory_info().rss
    return total


def accept_200(status: int) -> bool:
    return status == 200


def accept_any_answer(status: int) -> bool:
    """Any HTTP answer but a 5xx: the server is up (the bare app has no /health)."""
    return status < 500


class Server:
    """A server under test as a subprocess, in its own session, its output in
    ``log_path``; ready once ``GET health`` answers a status ``ready`` accepts."""

    def __init__(
        self,
        name: str,
        cmd: list[str],
        port: int,
        log_path: Path,
        env: dict[str, str] | None = None,
        health: str = "/health",
        ready: Callable[[int], bool] = accept_200,
    ):
        self.name, self.cmd, self.port, self.log_path = name, cmd, port, log_path
        self.env = env if env is not None else server_env()
        self.health, self.ready = health, ready
        self.url = f"http://{HOST}:{port}"
        self.proc: subprocess.Popen | None = None
        self.startup_s: float | None = None

    def start(self, timeout: float = 120.0) -> Server:
        t0 = time.monotonic()
        with open(self.log_path, "wb") as log:
            self.proc = subprocess.Popen(
                self.cmd,
                stdout=log,
                stderr=subprocess.STDOUT,
                stdin=subprocess.DEVNULL,
                env=self.env,
                start_new_session=True,
            )
        while time.monotonic() < t0 + timeout:
            if self.proc.poll() is not None:
                raise RuntimeError(
                    f"{self.name} exited with code {self.proc.returncode} during start-up\n{self.log_tail()}"
                )
            if self._answers():
                self.startup_s = time.monotonic() - t0
                return self
            time.sleep(0.05)
        self.kill()
        raise RuntimeError(f"{self.name} not ready after {timeout:.0f} s\n{self.log_tail()}")

    def _answers(self) -> bool:
        try:
            with urllib.request.urlopen(self.url + self.health, timeout=2) as r:
                return self.ready(r.status)
        except urllib.error.HTTPError as exc:
            return self.ready(exc.code)
        except (OSError, ValueError):
            return False

    def processes(self) -> list:
        return process_tree(self.proc.pid) if self.proc is not None else []

    def cpu_seconds(self) -> float:
        return cpu_seconds(self.processes())

    def rss_bytes(self) -> int | None:
        return rss_bytes(self.processes())

    def terminate(self, timeout: float = 120.0) -> tuple[int | None, float]:
        """SIGTERM and wait; (exit code, seconds it took). Killed, and an error, after ``timeout``."""
        if self.proc is None:
            return None, 0.0
        t0 = time.monotonic()
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(timeout)
            except subprocess.TimeoutExpired:
                self.kill()
                raise RuntimeError(
                    f"{self.name} did not exit within {timeout:.0f} s of SIGTERM\n{self.log_tail()}"
                ) from None
        return self.proc.returncode, time.monotonic() - t0

    def stop(self, timeout: float = 120.0) -> int | None:
        """SIGTERM, SIGKILL after ``timeout``; the exit code."""
        try:
            return self.terminate(timeout)[0]
        except RuntimeError:
            return self.proc.returncode if self.proc is not None else None

    def kill(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()

    def log_tail(self, n: int = 40) -> str:
        try:
            lines = self.log_path.read_text(errors="replace").splitlines()
        except OSError:
            return "(no log)"
        return "\n".join(f"  | {line}" for line in lines[-n:]) or "  | (empty log)"


def get(port: int, path: str, timeout: float = 30.0) -> tuple[int, bytes]:
    """One GET on the local server: (status, body), error statuses included."""
    try:
        with urllib.request.urlopen(f"http://{HOST}:{port}{path}", timeout=timeout) as r:
            return r.status, r.read()
    except urllib.error.HTTPError as exc:
        return exc.code, exc.read()


# --- loading through the store's write path ---------------------------------------------------


def is_pg(db: Path | str) -> bool:
    return str(db).startswith(("postgresql://", "postgres://"))


def finish_load(store, db, cluster) -> dict:
    """Make a freshly loaded store query-ready and close it: a full sort on
    DuckDB, VACUUM ANALYZE on PostgreSQL. Returns how long that took."""
    t0 = time.perf_counter()
    try:
        if is_pg(db):
            store.close()
            store = None
            if cluster is not None:
                cluster.vacuum_analyze()
        else:
            store.compact(full=True)
    finally:
        if store is not None:
            store.close()
    return {("vacuum_analyze_s" if is_pg(db) else "compact_s"): round(time.perf_counter() - t0, 1)}


def open_store(db: Path | str):
    """The store the server would open for ``--db``, opened in-process."""
    if is_pg(db):
        from tsdb_service.storage.postgres.store import PostgresStore

        return PostgresStore(str(db))
    from tsdb_service.storage.duckdb.store import DuckDBStore

    return DuckDBStore(str(db))


def bulk_load(db: Path | str, steps: Iterable[list], batch_notifications: int, progress_every: int = 0) -> tuple:
    """Write ``steps`` (lists of ``EntitySample``, one list per time step) through
    the store's own write path, ``batch_notifications`` per ``AppendSamples``.
    Returns (the open store, samples written, seconds); the store is closed on error."""
    from tsdb_service.write.ops import AppendSamples

    t0 = time.perf_counter()
    store = open_store(db)
    batch: list = []
    written = 0
    try:
        for i, step in enumerate(steps):
            for entity in step:
                batch.append(entity)
                written += len(entity.attrs)
                if len(batch) >= batch_notifications:
                    store.write_sync([AppendSamples(batch)])
                    batch = []
            if progress_every and i % progress_every == progress_every - 1:
                print(f"  loaded {written:,} samples ({time.perf_counter() - t0:.0f} s)", flush=True)
        if batch:
            store.write_sync([AppendSamples(batch)])
        return store, written, time.perf_counter() - t0
    except BaseException:
        store.close()
        raise


# --- the machine ------------------------------------------------------------------------------


def loadavg(digits: int | None = 2) -> list[float]:
    """The 1/5/15-minute load averages; on a shared machine they say how much a figure is worth."""
    try:
        values = os.getloadavg()
    except OSError:
        return []
    return [round(x, digits) if digits is not None else x for x in values]


def load_text(values: Iterable[float] | None = None, digits: int = 1) -> str:
    """``a / b / c``: load averages for a progress line."""
    return " / ".join(f"{x:.{digits}f}" for x in (loadavg(None) if values is None else values))


def machine() -> dict:
    return {"cpus": os.cpu_count(), "python": platform.python_version(), "platform": platform.platform()}


def speed_probe(directory: Path | str, loops: int = 2_000_000, syncs: int = 100) -> dict:
    """How fast this machine is right now: the median of three timings of a
    fixed pure-Python loop, and the median ``fsync`` of a 4 KiB append in
    ``directory`` (the disk the databases write to).

    On a virtual machine whose host is shared the load average says nothing
    of the neighbours: on 2026-11-27 this probe read 60 to 105 ms within one
    afternoon, at load averages below 2. Printed at the start and the end of
    a run, these two figures tell a slow hour from a slow change."""
    timings = []
    for _ in range(3):
        t0 = time.perf_counter()
        total = 0
        for i in range(loops):
            total += i
        timings.append(time.perf_counter() - t0)
    path = Path(directory) / f".speed-probe-{os.getpid()}"
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o600)
    waits = []
    try:
        for _ in range(syncs):
            os.write(fd, b"\0" * 4096)
            t0 = time.perf_counter()
            os.fsync(fd)
            waits.append(time.perf_counter() - t0)
    finally:
        os.close(fd)
        path.unlink(missing_ok=True)
    return {
        "python_loop_ms": round(statistics.median(timings) * 1000, 1),
        "fsync_ms": round(statistics.median(waits) * 1000, 3),
    }


def speed_text(probe: dict) -> str:
    """``python loop 140 ms, fsync 0.25 ms`` for a progress line."""
    return f"python loop {probe['python_loop_ms']:.0f} ms, fsync {probe['fsync_ms']:.2f} ms"


# --- figures ----------------------------------------------------------------------------------


def spread(values: Iterable[float | None]) -> dict | None:
    """Median, min, max and count of the values that are numbers (None and NaN skipped)."""
    kept = [v for v in values if v is not None and not (isinstance(v, float) and math.isnan(v))]
    if not kept:
        return None
    return {"median": statistics.median(kept), "min": min(kept), "max": max(kept), "n": len(kept)}


def spread_text(values: Iterable[float | None], digits: int = 2, thousands: bool = False) -> str:
    """``median [min-max]`` (just the median when there is one value), ``-`` when none."""
    s = spread(values)
    if s is None:
        return "-"
    f = f"{{:{',' if thousands else ''}.{digits}f}}"
    if s["n"] == 1:
        return f.format(s["median"])
    return f"{f.format(s['median'])} [{f.format(s['min'])}-{f.format(s['max'])}]"


def percentiles(values: list[float], digits: int = 2) -> dict:
    """n, p50, p99 (nearest rank) and max; ``{}`` for no values."""
    if not values:
        return {}
    ordered = sorted(values)
    return {
        "n": len(ordered),
        "p50": round(statistics.median(ordered), digits),
        "p99": round(ordered[min(len(ordered) - 1, int(len(ordered) * 0.99))], digits),
        "max": round(ordered[-1], digits),
    }


def fmt(v: float | None, digits: int = 1) -> str:
    """A figure with thousands separators, ``-`` for none or NaN."""
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "-"
    return f"{v:,.{digits}f}"


def print_rows(header: list[str], rows: list[list], left: int = 1, widths: list[int] | None = None) -> None:
    """An aligned table: the first ``left`` columns to the left, the others to the
    right; each column as wide as its widest cell, or ``widths`` if wider."""
    cells = [[str(c) for c in row] for row in [header, *rows]]
    fitted = [max(len(row[i]) for row in cells) for i in range(len(header))]
    if widths is not None:
        fitted = [max(a, b) for a, b in zip(fitted, widths, strict=True)]
    for row in cells:
        print(
            "  ".join(c.ljust(w) if i < left else c.rjust(w) for i, (c, w) in enumerate(zip(row, fitted, strict=True)))
        )


def print_scenarios(results: dict[str, dict], db_col: bool, label_width: int, rps_digits: int) -> None:
    """The measured scenarios of queries.py and geo.py, one line each: rate,
    latencies, the server's (and the database's) CPU per request, errors."""

    def ms(value) -> str:
        return f"{value:>8.2f}" if value is not None else f"{'-':>8}"

    print(
        f"{'scenario':<{label_width}} {'conns':>5} {'req/s':>8} {'p50 ms':>8} {'p99 ms':>8} {'cpu ms/req':>10}"
        + (f" {'db ms/req':>9}" if db_col else "")
        + f" {'errors':>6}"
    )
    for r in results.values():
        print(
            f"{r['label']:<{label_width}} {r['connections']:>5} {r['rps']:>8.{rps_digits}f} "
            f"{ms(r['p50_ms'])} {ms(r['p99_ms'])} {r['server_cpu_ms_per_req']:>10.2f}"
            + (f" {r['db_cpu_ms_per_req']:>9.2f}" if db_col else "")
            + f" {r['errors'] + r['non_2xx']:>6}"
        )


def write_json(path: str | Path, doc, indent: int = 2) -> None:
    """A results file (``benchmarks/results/`` is git-ignored); values JSON has no type for become strings."""
    Path(path).write_text(json.dumps(doc, indent=indent, default=str) + "\n")
