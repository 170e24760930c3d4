"""Which request headers carry credentials, so that nothing we keep holds one.

A notification we refuse is kept with its headers (the rejected store), for
an operator to recover it; the credentials among them are kept only as
``[redacted]``.
"""

from __future__ import annotations

from collections.abc import Mapping

CREDENTIAL_HEADERS = frozenset({"authorization", "proxy-authorization", "x-auth-token", "cookie", "x-api-key"})
REDACTED = "[redacted]"


def redact_headers(headers: Mapping[str, str], key_header: str = "X-Api-Key") -> dict[str, str]:
    """A copy of ``headers`` whose credentials (``Authorization``, Keyrock's
    ``X-Auth-Token``, cookies, API keys, the configured key header) read
    ``[redacted]``: kept notifications say a credential was sent, never which."""
    secret = CREDENTIAL_HEADERS | {key_header.strip().lower()}
    return {name: REDACTED if name.lower() in secret else value for name, value in headers.items()}
