"""The NGSI-LD tenant (``NGSILD-Tenant``, ETSI GS CIM 009 clause 6.3.14).

Tenants are the NGSIv2 ones (``Fiware-Service``): the same names, stored
lower-cased as Orion does, so data written over either API is one tenant.
The rule is the one of every API (``ngsi.request_context``): both headers
may be sent when they name the same tenant; two different tenants are a 400
(``BadRequestData`` ProblemDetails, as every ``BadRequest`` under
``/ngsi-ld/``), never one silently preferred. Without either, the default
tenant (""), which always exists.
"""

from __future__ import annotations

from fastapi import Request

from tsdb_service.parse.request_context import tenant


def ld_tenant(request: Request) -> str:
    return tenant(request.headers.items())


def tenant_echo(request: Request) -> dict[str, str]:
    """Response headers naming the tenant a request was served for (the
    spec's responses carry ``NGSILD-Tenant`` when the request did)."""
    raw = request.headers.get("ngsild-tenant")
    return {"NGSILD-Tenant": raw} if raw else {}
