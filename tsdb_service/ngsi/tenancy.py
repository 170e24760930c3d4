"""Which tenant a request names: one rule for notifications and every query.

A tenant can be named by ``Fiware-Service`` (NGSIv2), ``NGSILD-Tenant``
(NGSI-LD) and, on the Grafana endpoints, a ``service`` query parameter
(Infinity datasources cannot always set headers). The rule:

* every selector that is present and not blank must name the same tenant
  (compared as stored: stripped and lower-cased), or the request is refused:
  storing a notification under one selector while a query reads the other
  would hide it, and silently preferring one would do the same;
* a tenant is 1 to 50 ASCII letters, digits or ``_`` (Orion's rule), checked
  before lower-casing so that non-ASCII letters which lower-case to ASCII
  (the Kelvin sign) are refused;
* no selector at all is the default tenant ``""``.

Pure: callers turn ``TenantProblem`` into their own error (a notification's
``ParseError``, a query's ``BadRequest``).
"""

from __future__ import annotations

import re
from collections.abc import Iterable

TENANT_HEADERS = ("fiware-service", "ngsild-tenant")
_TENANT = re.compile(r"[A-Za-z0-9_]{1,50}\Z")


class TenantProblem(ValueError):
    """The selectors do not name one valid tenant (the message says why)."""


def selectors(headers: Iterable[tuple[str, str]]) -> list[tuple[str, str]]:
    """``(name, raw value)`` of every tenant header, duplicates included,
    blank ones left out. ``headers`` are ``(name, value)`` pairs, as
    ``Mapping.items()`` or Starlette's ``Headers.items()`` (which keeps
    repeated headers) give them."""
    out = []
    for name, value in headers:
        low = name.lower()
        if low in TENANT_HEADERS and value.strip():
            out.append((low, value))
    return out


def select_tenant(chosen: list[tuple[str, str]]) -> str:
    """The one tenant the selectors name, lower-cased; ``""`` without any."""
    if not chosen:
        return ""
    names = {raw.strip().lower() for _, raw in chosen}
    if len(names) > 1:
        listed = ", ".join(f"{name} {raw.strip()[:60]!r}" for name, raw in chosen)
        raise TenantProblem(f"conflicting tenant selectors ({listed}): name one tenant, or the same one in each")
    raw = chosen[0][1].strip()
    if not _TENANT.match(raw):
        raise TenantProblem(f"invalid tenant {raw[:60]!r}: use 1 to 50 letters, digits or underscores")
    return raw.lower()


def raw_tenant(chosen: list[tuple[str, str]]) -> str:
    """The tenant as received, for keeping a refused notification: the
    selectors' values joined by ``,`` when they conflict. ``,`` is never in
    a valid tenant, so such a record shows only in the operator listing."""
    return ",".join(dict.fromkeys(raw.strip() for _, raw in chosen))
