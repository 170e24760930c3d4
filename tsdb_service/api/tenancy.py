"""Tenant and service-path headers, read the way Orion writes them."""

from __future__ import annotations

import re

from fastapi import Request

from ..errors import BadRequest

_TENANT = re.compile(r"^[A-Za-z0-9_]{1,50}$")


def tenant_header(request: Request) -> str:
    """The tenant header exactly as received ("" without one)."""
    return request.headers.get("fiware-service") or request.headers.get("ngsild-tenant") or ""


def tenant_of(request: Request) -> str:
    """``Fiware-Service`` (or ``NGSILD-Tenant``) lower-cased, as Orion stores it;
    "" is the default tenant."""
    raw = tenant_header(request).strip()
    if not raw:
        return ""
    if not _TENANT.match(raw):
        raise BadRequest(
            f"bad Fiware-Service {raw[:60]!r}: use up to 50 letters, digits or underscores",
            error="BadRequest",
        )
    return raw.lower()
