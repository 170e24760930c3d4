"""Fetching a URL that a request names, without letting the request aim us.

A JSON-LD ``@context`` is a URL the *client* chooses, and fetching it
makes this service send an HTTP request from inside the operator's network.
Unchecked, that is server-side request forgery: the metadata service at
``169.254.169.254``, an admin port on loopback, a database on the private
network, and the error texts a port scanner. So ``fetch``:

* accepts only ``http``/``https`` URLs without user info;
* unless the URL is under one of the operator's allowed prefixes
  (``TSDB_LD_CONTEXT_ALLOW``; compared by parts, not as text: scheme, host
  and effective port exactly, then the path segment by segment, see
  ``core.urlprefix``), resolves the host and refuses it if **any**
  address is not public (loopback, private, link-local, shared, reserved,
  multicast; IPv4 inside IPv6 is judged as IPv4);
* connects to an address it checked (the URL's host is replaced by that
  address, the next one tried if it refuses the connection; ``Host`` and,
  for TLS, SNI and certificate verification keep the name), so a second
  DNS answer cannot swap in another address;
* follows at most ``max_redirects`` redirects itself, each one checked again;
* gives up after ``deadline`` seconds in all (name resolution, connection,
  redirects and the whole body: a server sending a byte a second does not
  keep us), and waits for a free slot among ``MAX_CONCURRENT`` fetches
  within that time;
* reads at most ``max_bytes`` *after* decompression, decompressing
  (``gzip``/``deflate`` only) piece by piece with a cap, so a small
  compressed bomb costs no more than ``max_bytes``;
* ignores proxy variables (a proxy would connect where we never checked).

``post`` sends a request body (``POST /v2/subscribe``'s subscription to the
broker a client names) under the same rules, following no redirect: what
is sent goes to the URL named, and the answer (its status, headers and at
most ``max_bytes`` of its body) is the caller's to judge.

It runs on the event loop (httpx's async client): a slow server costs a
waiting coroutine, never a worker thread. Failures raise ``FetchFailed``
whose message is for the operator's log only; callers answer clients with a
fixed text that tells nothing about the network.
"""

from __future__ import annotations

import asyncio
import ipaddress
import socket
import zlib
from dataclasses import dataclass, field
from urllib.parse import urljoin

import anyio
import httpx

from tsdb_service.core.urlprefix import UrlPrefix, allowed, canonical_host

MAX_CONCURRENT = 8
_REDIRECTS = frozenset({301, 302, 303, 307, 308})
_NAT64 = ipaddress.ip_network("64:ff9b::/96")


class FetchFailed(Exception):
    """The URL was refused or could not be fetched; the message is for the log."""


@dataclass(frozen=True, slots=True)
class FetchPolicy:
    """What ``fetch`` may do: ``allow`` lists URL prefixes exempt from the
    address check (e.g. ``http://127.0.0.1:``, any port of that host)."""

    deadline: float = 2.0
    max_bytes: int = 1 << 20
    max_redirects: int = 3
    allow: tuple[UrlPrefix, ...] = ()
    accept: str = "*/*"
    semaphore: asyncio.Semaphore = field(default_factory=lambda: asyncio.Semaphore(MAX_CONCURRENT), compare=False)

    def __post_init__(self) -> None:
        """Prefixes given as text are parsed here (ValueError on a bad one)."""
        parsed = tuple(p if isinstance(p, UrlPrefix) else UrlPrefix.parse(p) for p in self.allow)
        object.__setattr__(self, "allow", parsed)


def is_public(address: str) -> bool:
    """Is ``address`` reachable on the public internet, and nothing else
    (IPv4 mapped into IPv6, 6to4, Teredo and NAT64 judged by the IPv4 they carry)?"""
    ip: ipaddress.IPv4Address | ipaddress.IPv6Address = ipaddress.ip_address(address.split("%", 1)[0])
    if isinstance(ip, ipaddress.IPv6Address):
        embedded = ip.ipv4_mapped or ip.sixtofour or (ip.teredo[1] if ip.teredo else None)
        if embedded is None and ip in _NAT64:
            embedded = ipaddress.IPv4Address(int(ip) & 0xFFFFFFFF)
        if embedded is not None and not is_public(str(embedded)):
            return False
    return ip.is_global and not ip.is_multicast


def _allowed(url: httpx.URL, allow: tuple[UrlPrefix, ...]) -> bool:
    """Is ``url`` (as ``_checked`` parsed it) under one of the ``allow`` prefixes?
    Compared as sent: the host in its ASCII form, the path percent-encoded."""
    if not allow:
        return False
    path = url.raw_path.split(b"?", 1)[0].decode("ascii")
    return allowed(allow, url.scheme, canonical_host(url.raw_host.decode("ascii")), url.port, path)


def _checked(url: str) -> httpx.URL:
    """``url`` as httpx reads it, or ``FetchFailed``: http(s), a host, no user info."""
    try:
        parsed = httpx.URL(url)
    except (httpx.InvalidURL, ValueError, TypeError) as exc:
        raise FetchFailed(f"{url[:200]!r} is not a URL: {exc}") from None
    if parsed.scheme not in ("http", "https") or not parsed.host:
        raise FetchFailed(f"{url[:200]!r} is not an http(s) URL with a host")
    if parsed.userinfo:
        raise FetchFailed(f"{url[:200]!r} carries user info")
    return parsed


async def _addresses(url: httpx.URL, allowed: bool) -> list[str]:
    """The addresses to connect to, in the resolver's order: every address
    the host resolves to must be public unless the URL is allowed."""
    port = url.port or (443 if url.scheme == "https" else 80)
    try:
        infos = await anyio.getaddrinfo(url.host, port, type=socket.SOCK_STREAM)
    except OSError as exc:
        raise FetchFailed(f"cannot resolve {url.host!r}: {exc}") from None
    addresses = list(dict.fromkeys(str(info[4][0]) for info in infos))
    if not addresses:
        raise FetchFailed(f"{url.host!r} has no address")
    if not allowed:
        private = [a for a in addresses if not is_public(a)]
        if private:
            raise FetchFailed(f"{url.host!r} resolves to the non-public address {private[0]}")
    return addresses


async def fetch(url: str, policy: FetchPolicy) -> bytes:
    """The body of ``url`` (status 200), at most ``policy.max_bytes`` after
    decompression; ``FetchFailed`` otherwise (see the module docstring)."""
    try:
        with anyio.fail_after(policy.deadline):
            async with policy.semaphore:
                return await _follow(url, policy)
    except TimeoutError:
        raise FetchFailed(f"{url[:200]!r}: not complete within {policy.deadline} s") from None


@dataclass(frozen=True, slots=True)
class Answer:
    """What a server answered to ``post``."""

    status: int
    reason: str
    headers: httpx.Headers
    body: bytes


async def post(url: str, content: bytes, headers: dict[str, str], policy: FetchPolicy) -> Answer:
    """POST ``content`` to ``url`` under ``policy`` (no redirect followed);
    ``FetchFailed`` if refused, unreachable, late or answered too long."""
    try:
        with anyio.fail_after(policy.deadline):
            async with policy.semaphore:
                return await _post(url, content, headers, policy)
    except TimeoutError:
        raise FetchFailed(f"{url[:200]!r}: not complete within {policy.deadline} s") from None


async def _post(url: str, content: bytes, headers: dict[str, str], policy: FetchPolicy) -> Answer:
    async with httpx.AsyncClient(trust_env=False, follow_redirects=False, timeout=None) as client:
        target = _checked(url)
        addresses = await _addresses(target, _allowed(target, policy.allow))
        sent = _Sent("POST", {**headers, "Accept": policy.accept}, content)
        response = await _connect(client, target, addresses, policy.accept, sent)
        try:
            body = await _body(response, policy.max_bytes, url)
            return Answer(response.status_code, response.reason_phrase, response.headers, body)
        finally:
            await response.aclose()


@dataclass(frozen=True, slots=True)
class _Sent:
    method: str = "GET"
    headers: dict[str, str] = field(default_factory=dict)
    content: bytes | None = None


async def _follow(url: str, policy: FetchPolicy) -> bytes:
    async with httpx.AsyncClient(trust_env=False, follow_redirects=False, timeout=None) as client:
        for _ in range(policy.max_redirects + 1):
            target = _checked(url)
            addresses = await _addresses(target, _allowed(target, policy.allow))
            response = await _connect(client, target, addresses, policy.accept)
            try:
                if response.status_code in _REDIRECTS and response.headers.get("location"):
                    url = urljoin(url, response.headers["location"])
                    continue
                if response.status_code != 200:
                    raise FetchFailed(f"{url[:200]!r} answered HTTP {response.status_code}")
                return await _body(response, policy.max_bytes, url)
            finally:
                await response.aclose()
    raise FetchFailed(f"more than {policy.max_redirects} redirects from {url[:200]!r}")


async def _connect(
    client: httpx.AsyncClient, target: httpx.URL, addresses: list[str], accept: str, sent: _Sent | None = None
) -> httpx.Response:
    """Send ``sent`` (a GET by default) to ``target`` at the first of the
    checked ``addresses`` that accepts a connection (the name stays in Host
    and SNI)."""
    sent = sent or _Sent()
    failure: Exception | None = None
    for address in addresses:
        fixed = {"Host": target.netloc.decode("ascii"), "Accept": accept, "Accept-Encoding": "gzip, deflate"}
        request = client.build_request(
            sent.method,
            target.copy_with(host=address),
            headers={**sent.headers, **fixed},
            content=sent.content,
            extensions={"sni_hostname": target.host} if target.scheme == "https" else {},
        )
        try:
            return await client.send(request, stream=True)
        except httpx.ConnectError as exc:
            failure = exc
        except httpx.HTTPError as exc:
            raise FetchFailed(f"{str(target)[:200]!r}: {type(exc).__name__} {exc}") from None
    raise FetchFailed(f"{str(target)[:200]!r}: {type(failure).__name__} {failure}")


async def _body(response: httpx.Response, limit: int, url: str) -> bytes:
    """The decoded body, refused as soon as it passes ``limit`` bytes."""
    encoding = response.headers.get("content-encoding", "identity").strip().lower()
    if encoding in ("", "identity"):
        declared = response.headers.get("content-length", "")
        if declared.isdigit() and int(declared) > limit:
            raise FetchFailed(f"{url[:200]!r} declares {declared} bytes, more than {limit}")
        inflate = None
    elif encoding in ("gzip", "x-gzip"):
        inflate = zlib.decompressobj(16 + zlib.MAX_WBITS)
    elif encoding == "deflate":
        inflate = zlib.decompressobj()
    else:
        raise FetchFailed(f"{url[:200]!r} answered in the unsupported content encoding {encoding[:40]!r}")
    out = bytearray()
    try:
        async for raw in response.aiter_raw():
            if inflate is None:
                out += raw
            else:
                data = raw
                while data and len(out) <= limit:  # never inflate more than the limit allows
                    out += inflate.decompress(data, limit + 1 - len(out))
                    data = inflate.unconsumed_tail
            if len(out) > limit:
                raise FetchFailed(f"{url[:200]!r} is larger than {limit} bytes")
    except zlib.error as exc:
        raise FetchFailed(f"{url[:200]!r}: broken {encoding} body ({exc})") from None
    except httpx.HTTPError as exc:
        raise FetchFailed(f"{url[:200]!r}: {type(exc).__name__} {exc}") from None
    return bytes(out)
