"""Drive a server with wrk (https://github.com/wg/wrk), the load generator of issue 15's table.

wrk is a C load generator with per-thread Lua states: it costs the server's
cores far less than any Python client, so its ceiling is the server's. Two
scripts are generated here:

- ``post_script``: every request a distinct notification body, built in Lua
  from a ``string.format`` template and a per-thread counter (sequence
  ``counter * threads + thread``), so every notification is unique and can be
  checked in the store afterwards;
- ``get_script``: a random path from a list per request.

``done()`` prints one ``WRKJSON {...}`` line (requests, non-2xx, socket
errors, latency percentiles in microseconds) that ``run`` parses. wrk measures
closed-loop like ``loadgen.py``: each connection sends its next request when
the answer arrived. It has no warm-up of its own; callers run a short
separate invocation first.

``ensure_wrk()`` installs the Debian package with apt-get when wrk is missing
and we are root; otherwise callers fall back to ``loadgen.py``.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import tempfile
from dataclasses import dataclass
from pathlib import Path

_DONE = r"""
function done(summary, latency, requests)
  local e = summary.errors
  io.write(string.format(
    'WRKJSON {"requests":%d,"duration_us":%d,"non_2xx":%d,"connect":%d,"read":%d,"write":%d,' ..
    '"timeout":%d,"p50_us":%d,"p90_us":%d,"p99_us":%d,"max_us":%d,"mean_us":%f}\n',
    summary.requests, summary.duration, e.status, e.connect, e.read, e.write, e.timeout,
    latency:percentile(50), latency:percentile(90), latency:percentile(99), latency.max, latency.mean))
end
"""


def _lua_string(s: str) -> str:
    """A Lua string literal: JSON's escapes are Lua's for printable ASCII."""
    if not s.isascii():
        raise ValueError(f"wrk scripts take ASCII only: {s!r}")
    return json.dumps(s)


def _headers_lua(headers: dict[str, str]) -> str:
    return "{" + ", ".join(f"[{_lua_string(k)}] = {_lua_string(v)}" for k, v in headers.items()) + "}"


def post_script(path: str, headers: dict[str, str], prelude: str, body_lua: str, threads: int) -> str:
    """A wrk script POSTing one new body per request.

    ``body_lua`` is a Lua expression over ``seq`` (an integer unique within
    the invocation) that evaluates to the body string; ``prelude`` defines
    what it uses."""
    return f"""
{prelude}
local threads_seen = 0
function setup(thread)
  thread:set("tid", threads_seen)
  threads_seen = threads_seen + 1
end
local counter = 0
local path = {_lua_string(path)}
local headers = {_headers_lua(headers)}
function request()
  local seq = counter * {threads} + tid
  counter = counter + 1
  return wrk.format("POST", path, headers, {body_lua})
end
{_DONE}"""


def get_script(paths: list[str], headers: dict[str, str]) -> str:
    """A wrk script GETting a random path of ``paths`` per request."""
    items = ",\n".join(_lua_string(p) for p in paths)
    return f"""
local paths = {{
{items}
}}
local headers = {_headers_lua(headers)}
function init(args)
  math.randomseed(os.time() + (tid or 0))
end
local threads_seen = 0
function setup(thread)
  thread:set("tid", threads_seen)
  threads_seen = threads_seen + 1
end
function request()
  return wrk.format("GET", paths[math.random(#paths)], headers)
end
{_DONE}"""


@dataclass
class WrkStats:
    requests: int
    ok: int
    non_2xx: int
    errors: int  # socket errors: connect, read, write, timeout
    seconds: float
    rps: float  # 2xx answers per second
    p50_ms: float
    p90_ms: float
    p99_ms: float
    max_ms: float
    mean_ms: float

    def to_dict(self) -> dict:
        return dict(self.__dict__)


def ensure_wrk() -> str | None:
    """wrk's path; installs Debian's ``wrk`` with apt-get when missing and root."""
    found = shutil.which("wrk")
    if found or os.geteuid() != 0 or shutil.which("apt-get") is None:
        return found
    env = dict(os.environ, DEBIAN_FRONTEND="noninteractive")
    subprocess.run(["apt-get", "install", "-y", "-q", "wrk"], env=env, capture_output=True, check=False)
    return shutil.which("wrk")


def run(
    url: str, script: str, connections: int, duration: float, threads: int = 2, timeout_s: float = 10.0
) -> WrkStats:
    """One wrk invocation against ``url`` (scheme://host:port); returns its figures."""
    wrk = ensure_wrk()
    if wrk is None:
        raise RuntimeError("wrk is not installed (apt-get install wrk)")
    threads = max(1, min(threads, connections))
    with tempfile.NamedTemporaryFile("w", suffix=".lua", delete=False) as f:
        f.write(script)
        script_path = f.name
    try:
        proc = subprocess.run(
            [
                wrk,
                "-t",
                str(threads),
                "-c",
                str(connections),
                "-d",
                f"{max(1, round(duration))}s",
                "--timeout",
                f"{timeout_s:g}s",
                "-s",
                script_path,
                url,
            ],
            capture_output=True,
            text=True,
            timeout=duration + timeout_s + 60,
        )
    finally:
        Path(script_path).unlink(missing_ok=True)
    line = next((ln for ln in proc.stdout.splitlines() if ln.startswith("WRKJSON ")), None)
    if proc.returncode != 0 or line is None:
        raise RuntimeError(f"wrk failed ({proc.returncode}): {proc.stderr.strip()[:500]} {proc.stdout[-500:]}")
    d = json.loads(line[len("WRKJSON ") :])
    seconds = d["duration_us"] / 1e6
    ok = d["requests"] - d["non_2xx"]
    return WrkStats(
        requests=d["requests"],
        ok=ok,
        non_2xx=d["non_2xx"],
        errors=d["connect"] + d["read"] + d["write"] + d["timeout"],
        seconds=seconds,
        rps=ok / seconds if seconds else 0.0,
        p50_ms=d["p50_us"] / 1000,
        p90_ms=d["p90_us"] / 1000,
        p99_ms=d["p99_us"] / 1000,
        max_ms=d["max_us"] / 1000,
        mean_ms=d["mean_us"] / 1000,
    )
