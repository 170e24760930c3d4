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

Authorisation happens here too, on the tenant the route will use: when
authentication is on, the guard (``security.guard``) leaves the verified
caller in the request's scope (``PRINCIPAL``), and ``tenant_of`` and
``grafana_scope`` refuse (403) a tenant the caller may not touch, on the
value they parsed, never on raw bytes. ``visible`` and
``require_every_tenant`` serve the answers that span tenants.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Protocol

from fastapi import Request
from starlette.datastructures import QueryParams

from tsdb_service.core.errors import Forbidden
from tsdb_service.core.query import Scope
from tsdb_service.http.store import store_of
from tsdb_service.parse.request_context import grafana_scope as parse_grafana_scope
from tsdb_service.parse.request_context import raw_tenant, selectors, tenant, tenant_hint

PRINCIPAL = "tsdb.principal"  # the scope key the guard leaves the verified caller under


class Caller(Protocol):
    """What a route may ask of the verified caller (``security.Principal``)."""

    name: str
    tenants: frozenset[str] | None

    def may(self, scope: str) -> bool: ...

    def may_touch(self, tenant: str) -> bool: ...


def caller_of(request: Request) -> Caller | None:
    """The verified caller; None when authentication is off."""
    return request.scope.get(PRINCIPAL)


def authorised(request: Request, tenant_name: str) -> str:
    """``tenant_name``, or 403 if the caller may not touch it."""
    caller = caller_of(request)
    if caller is not None and not caller.may_touch(tenant_name):
        raise Forbidden(refusal(tenant_name))
    return tenant_name


def refusal(tenant_name: str) -> str:
    return (
        f"this credential does not grant access to tenant {tenant_name[:60]!r}"
        if tenant_name
        else "this credential does not grant access to the default tenant"
    )


def selected_tenants(scope) -> list[str]:
    """Every tenant selector of an ASGI request as received: the tenant
    headers and Grafana's ``service`` parameters, parsed as the routes parse
    them (Starlette's query parameters, so ``%73ervice`` is ``service``);
    blank ones are absent, as for the routes."""
    headers = [(name.decode("latin-1"), value.decode("latin-1")) for name, value in scope["headers"]]
    services = QueryParams(scope.get("query_string", b"")).getlist("service")
    return [value for _, value in selectors(headers)] + [value for value in services if value.strip()]


def visible(request: Request, tenants: Iterable[str]) -> list[str]:
    """Those of ``tenants`` the caller may see (all when authentication is off)."""
    caller = caller_of(request)
    return [t for t in tenants if caller is None or caller.may_touch(t)]


def require_every_tenant(request: Request, what: str) -> None:
    """403 unless the caller is restricted to no tenant (or authentication is off)."""
    caller = caller_of(request)
    if caller is not None and caller.tenants is not None:
        raise Forbidden(f"{what} spans every tenant: only a credential not restricted to tenants may ask for it")


def tenant_header(request: Request) -> str:
    """The tenant selectors exactly as received ("" without any), joined by
    ``,`` when there are several different ones."""
    return raw_tenant(selectors(request.headers.items()))


def tenant_of(request: Request) -> str:
    """``Fiware-Service`` / ``NGSILD-Tenant`` lower-cased, as Orion stores
    them; "" is the default tenant. Conflicting selectors are a 400, a
    tenant the caller may not touch a 403."""
    return authorised(request, tenant(request.headers.items()))


def grafana_scope(request: Request) -> Scope:
    """A Grafana request's scope (the tenant headers and ``service``
    parameters, as the routes read them), or 403 for a tenant the caller may
    not touch."""
    scope = parse_grafana_scope(request.query_params, request.headers)
    authorised(request, scope.tenant)
    return scope


def tenant_echo(request: Request) -> dict[str, str]:
    """Response headers naming the tenant a request was served for (the
    NGSI-LD spec's responses carry ``NGSILD-Tenant`` when the request did)."""
    raw = request.headers.get("ngsild-tenant")
    return {"NGSILD-Tenant": raw} if raw else {}


HINT_HEADER = "X-Tsdb-Hint"


def empty_answer_hint(request: Request, asked: str) -> dict[str, str]:
    """The ``X-Tsdb-Hint`` header for an empty answer (``{}`` when there is
    nothing to say): the tenants that hold data when ``asked`` holds none,
    limited to those the caller's credential may touch. A header, so the
    body stays QuantumLeap's ``[]``."""
    hint = tenant_hint(visible(request, store_of(request).querier().tenants()), asked)
    return {HINT_HEADER: f"{hint} (send Fiware-Service: TENANT)"} if hint else {}
