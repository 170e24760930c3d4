"""The tenant of a request, read the way Orion writes it.

The rule itself (which selectors count, when they conflict, what a valid
tenant is) lives in ``parse.request_context``, shared with the notification
parser, so a notification is always stored under the tenant a query with the
same headers reads. This module only takes the headers off a ``Request``.

NGSI-LD (``NGSILD-Tenant``, ETSI GS CIM 009 clause 6.3.14) has the NGSIv2
tenants (``Fiware-Service``): the same names, stored lower-cased as Orion
does, so data written over either API is one tenant. Both headers may be sent
when they name the same tenant; two different tenants are a 400, never one
silently preferred. Without either, the default tenant (""), which always
exists.
"""

from __future__ import annotations

from fastapi import Request

from tsdb_service.http.store import store_of
from tsdb_service.parse.request_context import raw_tenant, selectors, tenant, tenant_hint

HINT_HEADER = "X-Tsdb-Hint"


def tenant_header(request: Request) -> str:
    """The tenant selectors exactly as received ("" without any), joined by
    ``,`` when there are several different ones."""
    return raw_tenant(selectors(request.headers.items()))


def tenant_of(request: Request) -> str:
    """``Fiware-Service`` / ``NGSILD-Tenant`` lower-cased, as Orion stores
    them; "" is the default tenant. Conflicting selectors are a 400."""
    return tenant(request.headers.items())


def tenant_echo(request: Request) -> dict[str, str]:
    """Response headers naming the tenant a request was served for (the
    NGSI-LD spec's responses carry ``NGSILD-Tenant`` when the request did)."""
    raw = request.headers.get("ngsild-tenant")
    return {"NGSILD-Tenant": raw} if raw else {}


def empty_answer_hint(request: Request, asked: str) -> dict[str, str]:
    """The ``X-Tsdb-Hint`` header for an empty answer (``{}`` when there is
    nothing to say): the tenants that hold data when ``asked`` holds none,
    limited to those the caller's credential may touch. A header, so the
    body stays QuantumLeap's ``[]``."""
    principal = getattr(request.state, "principal", None)
    tenants = store_of(request).querier().tenants()
    visible = [t for t in tenants if principal is None or principal.may_touch(t)]
    hint = tenant_hint(visible, asked)
    return {HINT_HEADER: f"{hint} (send Fiware-Service: TENANT)"} if hint else {}
