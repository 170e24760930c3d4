"""The NGSI-LD tenant (``NGSILD-Tenant``, ETSI GS CIM 009 clause 6.3.14).

Tenants are the NGSIv2 ones (``Fiware-Service``): the same names, stored
lower-cased as Orion does, so data written over either API is one tenant.
``NGSILD-Tenant`` wins when both headers are sent; without either, the
default tenant (""), which always exists.
"""

from __future__ import annotations

import re

from fastapi import Request

from .errors import BadRequestData

_TENANT = re.compile(r"[A-Za-z0-9_]{1,50}\Z")


def tenant_header(request: Request) -> str | None:
    """The tenant header as received, or None."""
    return request.headers.get("ngsild-tenant") or request.headers.get("fiware-service")


def ld_tenant(request: Request) -> str:
    raw = (tenant_header(request) or "").strip()
    if not raw:
        return ""
    if not _TENANT.match(raw):
        raise BadRequestData(f"bad NGSILD-Tenant {raw[:60]!r}: use up to 50 letters, digits or underscores")
    return raw.lower()


def tenant_echo(request: Request) -> dict[str, str]:
    """Response headers naming the tenant a request was served for (the
    spec's responses carry ``NGSILD-Tenant`` when the request did)."""
    raw = request.headers.get("ngsild-tenant")
    return {"NGSILD-Tenant": raw} if raw else {}
