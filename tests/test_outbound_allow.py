"""Outbound allow-lists compare scheme, host and port exactly, then the path by segments (issue 37, finding 9).

``TSDB_SUBSCRIBE_BROKER_ALLOW`` and ``TSDB_LD_CONTEXT_ALLOW`` were compared
as text prefixes: allowing ``http://127.0.0.1:2000`` allowed port 20000,
``http://orion`` allowed ``http://orion.attacker.example``. The parsing is
checked first (``core.urlprefix``), then ``http.outbound`` against a real
HTTP server on loopback: a prefix that names another port or a longer path
segment must not exempt it from the address check.
"""

from __future__ import annotations

import asyncio
from http.server import BaseHTTPRequestHandler

import httpx
import pytest

from tests.support.local_http import LocalServer
from tsdb_service.core.config import Settings
from tsdb_service.core.urlprefix import UrlPrefix, canonical_host, url_prefixes
from tsdb_service.http import outbound


def matches(prefix: str, url: str) -> bool:
    """As ``http.outbound`` asks: the URL parsed by httpx, compared by parts."""
    target = httpx.URL(url)
    path = target.raw_path.split(b"?", 1)[0].decode("ascii")
    host = canonical_host(target.raw_host.decode("ascii"))
    return UrlPrefix.parse(prefix).matches(target.scheme, host, target.port, path)


@pytest.mark.parametrize(
    ("prefix", "url"),
    [
        ("http://127.0.0.1:2000", "http://127.0.0.1:2000/v2/subscriptions"),
        ("http://orion", "http://orion/v2"),
        ("http://orion", "http://ORION:80/v2"),  # host case, the default port spelled out
        ("http://orion:80/", "http://orion/"),
        ("https://orion", "https://orion:443/x"),
        ("http://orion:1026/v2", "http://orion:1026/v2"),
        ("http://orion:1026/v2", "http://orion:1026/v2/subscriptions"),
        ("http://orion:1026/v2/", "http://orion:1026/v2/subscriptions?limit=1"),
        ("http://[::1]:1026", "http://[0:0::1]:1026/v2"),  # IPv6, any spelling of the address
        ("http://bücher.example", "http://xn--bcher-kva.example/"),  # IDNA
        ("http://xn--bcher-kva.example", "http://BÜCHER.example/"),
        ("http://127.0.0.1:", "http://127.0.0.1:9/x"),  # ':' and no port: any port of the host
    ],
)
def test_allowed(prefix, url):
    assert matches(prefix, url)


@pytest.mark.parametrize(
    ("prefix", "url"),
    [
        ("http://127.0.0.1:2000", "http://127.0.0.1:20000/"),  # the finding: a port that starts the same
        ("http://127.0.0.1:2000", "http://127.0.0.1/"),
        ("http://orion", "http://orion.attacker.example/"),  # the finding: a host that starts the same
        ("http://orion", "http://orion:8080/"),  # no port: the scheme's, not any
        ("http://orion", "https://orion/"),
        ("https://orion", "http://orion:443/"),
        ("http://orion:1026/v2", "http://orion:1026/v2x"),  # a path prefix is whole segments
        ("http://orion:1026/v2", "http://orion:1026/v"),
        ("http://orion:1026/v2/", "http://orion:1026/v2x/subscriptions"),
        ("http://orion", "http://orion@evil/"),  # user info: the host is evil
        ("http://orion:1026", "http://orion:1026@evil/"),
        ("http://[::1]:1026", "http://[::2]:1026/"),
        ("http://10.0.0.1", "http://10.0.0.10/"),
        ("http://127.0.0.1:", "http://127.0.0.10:9/"),
    ],
)
def test_refused(prefix, url):
    assert not matches(prefix, url)


@pytest.mark.parametrize(
    "bad",
    ["ftp://orion", "http://", "orion:1026", "http://user@orion", "http://orion:99999", "http://orion/?q=1", "//o"],
)
def test_bad_prefixes_are_refused_at_start(bad):
    with pytest.raises(ValueError, match="http"):
        url_prefixes(bad)
    with pytest.raises(ValueError):
        Settings(subscribe_broker_allow=bad)


def test_both_settings_share_the_rule():
    allow = "http://orion:1026/v2, http://127.0.0.1:"
    assert Settings(subscribe_broker_allow=allow, ld_context_allow=allow)
    parsed = url_prefixes(allow)
    assert [(p.host, p.port, p.path) for p in parsed] == [("orion", 1026, "/v2"), ("127.0.0.1", None, "")]


class _Ok(LocalServer):
    def _handler(self) -> type:
        class Handler(BaseHTTPRequestHandler):
            def do_GET(self) -> None:
                body = b'{"ok": true}'
                self.send_response(200)
                self.send_header("Content-Length", str(len(body)))
                self.end_headers()
                self.wfile.write(body)

            do_POST = do_GET

            def log_message(self, *args) -> None:
                pass

        return Handler


def _fetch(url: str, allow: str) -> bytes:
    policy = outbound.FetchPolicy(deadline=5.0, allow=url_prefixes(allow))
    return asyncio.run(outbound.fetch(url, policy))


def _post(url: str, allow: str) -> int:
    policy = outbound.FetchPolicy(deadline=5.0, allow=url_prefixes(allow))
    return asyncio.run(outbound.post(url, b"{}", {"Content-Type": "application/json"}, policy)).status


def test_outbound_compares_ports_and_segments():
    """A loopback server is reachable only through a prefix naming its
    exact port; a prefix of its port's digits, or of a longer path segment,
    leaves the address check on (loopback: refused)."""
    with _Ok() as server:
        port = str(server.port)
        url = f"{server.url}/v2/subscriptions"
        assert _fetch(url, f"http://127.0.0.1:{port}") == b'{"ok": true}'
        assert _post(url, f"http://127.0.0.1:{port}/v2") == 200
        assert _post(url, "http://127.0.0.1:") == 200
        for allow in (f"http://127.0.0.1:{port[:-1]}", f"http://127.0.0.1:{port}/v", "http://127.0.0.1"):
            with pytest.raises(outbound.FetchFailed, match="non-public"):
                _fetch(url, allow)
            with pytest.raises(outbound.FetchFailed, match="non-public"):
                _post(url, allow)
        with pytest.raises(outbound.FetchFailed, match="user info"):
            _fetch(f"http://127.0.0.1:{port}@127.0.0.1:{port}/v2", f"http://127.0.0.1:{port}")
