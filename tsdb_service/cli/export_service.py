"""``tsdb-service export`` through a running service: ``GET /v2/export``.

A DuckDB file belongs to one process. While the service has it open,
``export --db FILE`` cannot open it; the service can export it, with the
same parameters and headers. So ``export`` asks the service: the one at
``--url``, or, when the file is held and the holder is a tsdb-service
listening on this machine, that one (found through ``/proc``: the holder's
PID from DuckDB's lock message, its listening sockets from the process's
file descriptors). Anywhere else (another machine's process, a container,
no ``/proc``) the operator gets one line with the request to make.

Invariants: the output file appears whole or not at all (the download goes
to a temporary file next to it, renamed at the end); a credential is only
ever sent as ``Authorization: Bearer`` from ``TSDB_CLIENT_TOKEN``, never
taken from the command line (``ps`` shows it).
"""

from __future__ import annotations

import os
import re
import socket
import tempfile
import time
from collections.abc import Mapping
from pathlib import Path

TOKEN_VARIABLE = "TSDB_CLIENT_TOKEN"
_LISTEN = "0A"  # TCP_LISTEN in /proc/net/tcp's state column
_PID = re.compile(r"\(PID (\d+)\)")


class ServiceExportError(RuntimeError):
    """The export through the service failed; the message is one line."""


def lock_holder(path: str) -> int | None:
    """The PID of the process that holds the DuckDB file ``path`` locked, or
    None (not locked, not a DuckDB file, or DuckDB did not name the holder)."""
    import duckdb

    try:
        duckdb.connect(path, read_only=True).close()
    except duckdb.Error as exc:
        text = str(exc)
        found = _PID.search(text)
        return int(found[1]) if found and "lock" in text.lower() else None
    return None


def service_url(pid: int) -> str | None:
    """``http://HOST:PORT`` of the tsdb-service that process ``pid`` runs on
    this machine, or None when it listens on nothing we can see or what
    listens is not a tsdb-service."""
    for host, port in listening(pid):
        url = f"http://{f'[{host}]' if ':' in host else host}:{port}"
        if _is_tsdb_service(url):
            return url
    return None


def listening(pid: int) -> list[tuple[str, int]]:
    """The TCP addresses process ``pid`` listens on (a wildcard address as
    loopback), from ``/proc``; empty where ``/proc`` does not tell."""
    proc = Path("/proc") / str(pid)
    try:
        sockets = {
            link[8:-1] for fd in os.listdir(proc / "fd") if (link := _link(proc / "fd" / fd)).startswith("socket:[")
        }
    except OSError:
        return []
    found = []
    for table, family in (("tcp", socket.AF_INET), ("tcp6", socket.AF_INET6)):
        try:
            rows = (proc / "net" / table).read_text().splitlines()[1:]
        except OSError:
            continue
        for row in rows:
            fields = row.split()
            if len(fields) > 9 and fields[3] == _LISTEN and fields[9] in sockets:
                address, port = fields[1].split(":")
                found.append((_loopback_for(_address(address, family)), int(port, 16)))
    return found


def _link(path: Path) -> str:
    try:
        return os.readlink(path)
    except OSError:  # closed meanwhile
        return ""


def _address(hex_address: str, family: int) -> str:
    """/proc/net/tcp's address: 32-bit words in the host's (little-endian) order."""
    raw = bytes.fromhex(hex_address)
    words = b"".join(raw[i : i + 4][::-1] for i in range(0, len(raw), 4))
    return socket.inet_ntop(family, words)


def _loopback_for(host: str) -> str:
    return {"0.0.0.0": "127.0.0.1", "::": "::1"}.get(host, host)


def _is_tsdb_service(url: str) -> bool:
    import httpx

    try:
        answer = httpx.get(f"{url}/version", timeout=5.0)
        return answer.status_code == 200 and isinstance(answer.json().get("version"), str)
    except (httpx.HTTPError, ValueError, AttributeError):
        return False


def export_url(url: str, params: Mapping[str, str]) -> str:
    """The request for the operator to make: ``URL/v2/export?format=csv&type=...``."""
    from urllib.parse import urlencode

    return f"{url.rstrip('/')}/v2/export?{urlencode(params)}"


def download(url: str, params: Mapping[str, str], headers: Mapping[str, str], out: str) -> tuple[int, float]:
    """``GET URL/v2/export`` streamed into ``out``: (bytes, seconds).
    ``ServiceExportError`` (one line) if the service cannot be reached or
    refuses; ``out`` is then left as it was."""
    import httpx

    base = url.rstrip("/")
    sent = {k: v for k, v in headers.items() if v}  # no Fiware-Service: the default tenant
    token = os.environ.get(TOKEN_VARIABLE, "").strip()
    if token:
        sent["Authorization"] = f"Bearer {token}"
    target = Path(out)
    fd, partial = tempfile.mkstemp(dir=target.parent, prefix=f".{target.name}.", suffix=".part")
    started = time.perf_counter()
    try:
        with (
            os.fdopen(fd, "wb") as file,
            httpx.stream(
                "GET", f"{base}/v2/export", params=dict(params), headers=sent, timeout=httpx.Timeout(60.0, connect=10.0)
            ) as answer,
        ):
            if answer.status_code != 200:
                raise ServiceExportError(_refusal(base, answer))
            for chunk in answer.iter_bytes():
                file.write(chunk)
        os.replace(partial, target)
    except httpx.HTTPError as exc:
        os.unlink(partial)
        raise ServiceExportError(f"cannot export through {base}: {exc or type(exc).__name__}") from None
    except BaseException:
        os.unlink(partial)
        raise
    return target.stat().st_size, time.perf_counter() - started


def _refusal(base: str, answer) -> str:
    answer.read()
    try:
        body = answer.json()
        reason = f"{body['error']}: {body['description']}"
    except (ValueError, KeyError, TypeError):
        reason = " ".join(answer.text.split())[:200] or answer.reason_phrase
    line = f"the service at {base} refused the export ({answer.status_code} {reason})"
    if answer.status_code in (401, 403):
        line += f"; set {TOKEN_VARIABLE} to an API key or token with the read scope"
    return line
