"""Allowed URL prefixes (``TSDB_LD_CONTEXT_ALLOW``, ``TSDB_SUBSCRIBE_BROKER_ALLOW``), compared by parts.

An operator's allow-list exempts some URLs from the outbound address check
(``http.outbound``), so it must allow exactly what it names. Compared as
text, ``http://127.0.0.1:2000`` allowed port 20000 and ``http://orion``
allowed ``http://orion.attacker.example``. So each prefix is parsed once
and a URL matches it only when:

* the **scheme** is the same;
* the **host** is the same: case-insensitive, internationalised names in
  their IDNA (``xn--``) form, IP addresses in their canonical spelling (an
  IPv6 address with or without brackets and zeros);
* the **port** is the same effective port (``http://h`` is ``http://h:80``,
  ``https://h`` is ``https://h:443``). The one exception is a prefix that
  ends in ``:`` with no port (``http://127.0.0.1:``): any port of that
  host, so a conformance run on one machine can fetch its local servers;
* the **path** starts with the prefix's path **segment by segment**:
  ``/v2`` allows ``/v2`` and ``/v2/...``, never ``/v2x``; no path (or
  ``/``) allows every path.

User info is never allowed in a prefix, and ``http.outbound`` refuses every
URL that carries some, so ``http://orion@evil`` is host ``evil`` and cannot
match ``http://orion``.
"""

from __future__ import annotations

import ipaddress
from dataclasses import dataclass
from urllib.parse import urlsplit

import idna

DEFAULT_PORTS = {"http": 80, "https": 443}
FORMAT = "URL prefixes are http(s)://host[:port][/path] without user info"


@dataclass(frozen=True, slots=True)
class UrlPrefix:
    """One allowed prefix, by parts (see the module docstring)."""

    text: str  # as the operator wrote it, for messages
    scheme: str
    host: str  # canonical_host()
    port: int | None  # None: any port (the prefix ended in ':')
    path: str  # '' (every path) or '/a/b' without a trailing '/'

    @classmethod
    def parse(cls, text: str) -> UrlPrefix:
        """The prefix ``text`` names, or ValueError saying why not."""
        try:
            parts = urlsplit(text)
            explicit_port = parts.port
        except ValueError:
            raise ValueError(f"{FORMAT}, not {text!r}") from None
        if parts.scheme not in DEFAULT_PORTS or not parts.hostname or "@" in parts.netloc:
            raise ValueError(f"{FORMAT}, not {text!r}")
        if parts.query or parts.fragment:
            raise ValueError(f"{FORMAT} (no query or fragment), not {text!r}")
        try:
            host = canonical_host(parts.hostname)
        except (ValueError, idna.IDNAError):
            raise ValueError(f"{FORMAT}, not {text!r}: {parts.hostname!r} is not a host name") from None
        any_port = explicit_port is None and parts.netloc.endswith(":")
        port = None if any_port else explicit_port or DEFAULT_PORTS[parts.scheme]
        return cls(text, parts.scheme, host, port, parts.path.rstrip("/"))

    def matches(self, scheme: str, host: str, port: int | None, path: str) -> bool:
        """Does the URL with these parts (``host`` as ``canonical_host``
        gives it, ``port`` None for the scheme's default) start with this prefix?"""
        if scheme != self.scheme or host != self.host:
            return False
        if self.port is not None and (port or DEFAULT_PORTS.get(scheme)) != self.port:
            return False
        if not self.path:
            return True
        return path == self.path or path.startswith(self.path + "/")


def canonical_host(host: str) -> str:
    """``host`` lower-cased, an IP address in its canonical spelling (IPv6
    without brackets), a name in its ASCII (IDNA) form; ValueError when it
    is neither."""
    bare = host.strip("[]")
    try:
        return str(ipaddress.ip_address(bare))
    except ValueError:
        pass
    if bare.isascii():
        return bare.lower()
    return idna.encode(bare.lower()).decode("ascii")  # as httpx encodes a host (IDNA 2008)


def url_prefixes(spec: str) -> tuple[UrlPrefix, ...]:
    """A comma list of URL prefixes, each parsed; ValueError on a bad one."""
    return tuple(UrlPrefix.parse(item.strip()) for item in spec.split(",") if item.strip())


def allowed(allow: tuple[UrlPrefix, ...], scheme: str, host: str, port: int | None, path: str) -> bool:
    """Does any prefix of ``allow`` allow this URL (parts as ``UrlPrefix.matches`` takes them)?"""
    return any(prefix.matches(scheme, host, port, path) for prefix in allow)
