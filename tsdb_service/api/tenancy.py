"""Tenant and service-path headers, read the way Orion writes them."""

from __future__ import annotations

import re
from collections.abc import Mapping

from fastapi import Request

from ..errors import BadRequest

_TENANT = re.compile(r"^[A-Za-z0-9_]{1,50}$")


def tenant_header(request: Request) -> str:
    """The tenant header exactly as received ("" without one)."""
    return _raw_tenant(request.headers)


def tenant_of(request: Request) -> str:
    """``Fiware-Service`` (or ``NGSILD-Tenant``) lower-cased, as Orion stores it;
    "" is the default tenant."""
    return tenant_from_headers(request.headers)


def tenant_from_headers(headers: Mapping[str, str]) -> str:
    """``tenant_of`` for header mappings that do not come with a request
    (the ``export`` command builds its headers from flags)."""
    raw = _raw_tenant(headers).strip()
    if not raw:
        return ""
    if not _TENANT.match(raw):
        raise BadRequest(
            f"bad Fiware-Service {raw[:60]!r}: use up to 50 letters, digits or underscores",
            error="BadRequest",
        )
    return raw.lower()


def _raw_tenant(headers: Mapping[str, str]) -> str:
    return headers.get("fiware-service") or headers.get("ngsild-tenant") or ""
