"""Tenant and service-path headers, read the way Orion writes them.

The rule itself (which selectors count, when they conflict, what a valid
tenant is) lives in ``ngsi.tenancy``, shared with the notification parser,
so a notification is always stored under the tenant a query with the same
headers reads.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping

from fastapi import Request

from ..errors import BadRequest
from ..ngsi.tenancy import TenantProblem, raw_tenant, select_tenant, selectors


def tenant_header(request: Request) -> str:
    """The tenant selectors exactly as received ("" without any), joined by
    ``,`` when there are several different ones."""
    return raw_tenant(selectors(request.headers.items()))


def tenant_of(request: Request, extra: Iterable[tuple[str, str]] = ()) -> str:
    """``Fiware-Service`` / ``NGSILD-Tenant`` (and ``extra`` selectors, such
    as Grafana's ``service`` parameter) lower-cased, as Orion stores them;
    "" is the default tenant. Conflicting selectors are a 400."""
    return tenant_from(request.headers.items(), extra)


def tenant_from_headers(headers: Mapping[str, str]) -> str:
    """``tenant_of`` for header mappings that do not come with a request."""
    return tenant_from(headers.items())


def tenant_from(headers: Iterable[tuple[str, str]], extra: Iterable[tuple[str, str]] = ()) -> str:
    """The tenant of ``(name, value)`` header pairs plus ``extra`` selectors."""
    chosen = selectors(headers) + [(name, value) for name, value in extra if value.strip()]
    try:
        return select_tenant(chosen)
    except TenantProblem as exc:
        raise BadRequest(f"bad tenant: {exc}", error="BadRequest") from None
