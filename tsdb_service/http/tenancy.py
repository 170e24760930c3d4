"""The tenant of a /v2 request, read the way Orion writes it.

The rule itself (which selectors count, when they conflict, what a valid
tenant is) lives in ``ngsi.request_context``, shared with the notification
parser, Grafana and NGSI-LD, so a notification is always stored under the
tenant a query with the same headers reads. This module only takes the
headers off a ``Request``.
"""

from __future__ import annotations

from fastapi import Request

from tsdb_service.parse.request_context import raw_tenant, selectors, tenant


def tenant_header(request: Request) -> str:
    """The tenant selectors exactly as received ("" without any), joined by
    ``,`` when there are several different ones."""
    return raw_tenant(selectors(request.headers.items()))


def tenant_of(request: Request) -> str:
    """``Fiware-Service`` / ``NGSILD-Tenant`` lower-cased, as Orion stores
    them; "" is the default tenant. Conflicting selectors are a 400."""
    return tenant(request.headers.items())
