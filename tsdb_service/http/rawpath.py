"""URL path segments that may contain ``/``: entity ids, types, attribute names.

NGSI-LD ids, types and attribute names are URIs (``urn:a/b``,
``https://example.org/ns/speed``); a client sends such a name as one path
segment with ``/`` percent-encoded (``/v2/entities/urn:a%2Fb``). The ASGI
server decodes the whole path before routing, so ``%2F`` would split the
segment: ``/v2/entities/urn:a%2Fvalue`` would even reach the ``/value``
route of entity ``urn:a``.

So for the history and delete routes (``HISTORY_PREFIXES``) the path is
rebuilt from the raw request path before routing: each raw segment is
decoded, then only ``%`` and ``/`` are escaped again (``%25``, ``%2F``).
Routing then splits on real separators only, and ``unescape_segment`` (below,
called by the route parsers for every path segment those routes take) restores
the exact name. Other routes are left alone.
"""

from __future__ import annotations

import re
from urllib.parse import unquote

HISTORY_PREFIXES = ("/v2/entities/", "/v2/types/", "/v2/attrs/")
_ESCAPED = re.compile("%2[5F]")
_UNESCAPE = {"%25": "%", "%2F": "/"}


def keep_encoded_slashes(scope) -> None:
    """Rewrite ``scope["path"]`` of a history route as described above.

    Only when the raw path has a ``%`` (otherwise the decoded path is the
    raw one) and the server's decoded path is exactly the raw path decoded
    (a proxy prefix or another rewrite: leave it alone)."""
    raw = scope.get("raw_path")
    path = scope["path"]
    if not raw or b"%" not in raw or not path.startswith(HISTORY_PREFIXES):
        return
    text = raw.decode("latin-1")
    if unquote(text) != path:
        return
    scope["path"] = "/".join(escape_segment(unquote(segment)) for segment in text.split("/"))


def escape_segment(text: str) -> str:
    return text.replace("%", "%25").replace("/", "%2F")


def unescape_segment(text: str) -> str:
    """The name a routed path segment stands for (identity without ``%``)."""
    if "%" not in text:
        return text
    return _ESCAPED.sub(lambda match: _UNESCAPE[match.group()], text)
