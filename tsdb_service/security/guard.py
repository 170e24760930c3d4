"""The ASGI guard: authenticate, then authorise, before anything else runs.

It sits in front of the notification fast path and of the framework alike,
so one set of rules covers every route, and an unauthenticated request is
answered before its body is read. It is not installed at all when no
credential is configured, so it costs nothing then.
"""

from __future__ import annotations

import logging

import orjson

from tsdb_service.core.errors import Forbidden, MissingCredential, TsdbError, Unauthorized
from tsdb_service.http.errors import internal_error
from tsdb_service.http.tenancy import PRINCIPAL, refusal, selected_tenants
from tsdb_service.security.keys import KeyRing
from tsdb_service.security.principals import Principal, normalise_tenant, required_scope
from tsdb_service.security.tokens import TokenVerifier, looks_like_jwt

log = logging.getLogger(__name__)

# What an orchestrator and a reader of the API description need, nothing more.
OPEN_PATHS = frozenset({"/health", "/version", "/docs", "/docs/oauth2-redirect", "/redoc", "/openapi.json"})
REALM = 'Bearer realm="tsdb-service"'


class Guard:
    """Pure ASGI middleware; ``keys`` and/or ``tokens`` are configured."""

    def __init__(self, app, keys: KeyRing | None, tokens: TokenVerifier | None, key_header: str):
        self.app, self.keys, self.tokens = app, keys, tokens
        self.key_header = key_header.strip().lower().encode("latin-1")

    async def __call__(self, scope, receive, send) -> None:
        if scope["type"] != "http" or route_path(scope) in OPEN_PATHS:
            await self.app(scope, receive, send)
            return
        try:
            principal = await self._authenticate(scope)
            _authorise(principal, scope)
            scope[PRINCIPAL] = principal  # routes authorise the tenant they parse (http.tenancy)
        except TsdbError as exc:
            await _refuse(send, exc)
            return
        except Exception:  # a bug in here must not leak more than any other 500
            await _refuse(send, TsdbError(internal_error("authentication failed")[1]["description"]))
            return
        await self.app(scope, receive, send)

    async def _authenticate(self, scope) -> Principal:
        """A configured key first (a cheap, constant-time lookup), then a JWT."""
        credential = self._credential(scope["headers"])
        principal = self.keys.lookup(credential) if self.keys is not None else None
        if principal is not None:
            return principal
        if self.tokens is not None and looks_like_jwt(credential):
            return await self.tokens.verify(credential)
        raise Unauthorized("the API key or token is not valid")

    def _credential(self, headers) -> str:
        """The one credential: ``Authorization: Bearer X`` or the key header."""
        found = []
        for name, value in headers:
            if name == b"authorization":
                scheme, _, token = value.decode("latin-1").strip().partition(" ")
                if scheme.lower() != "bearer" or not token.strip():
                    raise Unauthorized("use 'Authorization: Bearer <API key or token>'")
                found.append(token.strip())
            elif name == self.key_header:
                found.append(value.decode("latin-1").strip())
        if not found:
            raise MissingCredential(
                "authentication required: send 'Authorization: Bearer <API key or token>' "
                f"or a '{self.key_header.decode()}' header"
            )
        if len(set(found)) > 1:
            raise Unauthorized("send one credential, not several")
        return found[0]


def route_path(scope) -> str:
    """The path the router matches: without the ``root_path`` a proxy mounts
    us under, so a prefix cannot dodge the rules."""
    path, root = scope["path"], scope.get("root_path", "")
    return path[len(root) :] if root and path.startswith(root) else path


def _authorise(principal: Principal, scope) -> None:
    needed = required_scope(scope["method"], route_path(scope))
    if not principal.may(needed):
        log.info("%s lacks %s scope for %s %s", principal.name, needed, scope["method"], scope["path"])
        raise Forbidden(f"this credential does not grant the '{needed}' scope this request needs")
    for tenant in tenants_of(scope):
        if not principal.may_touch(tenant):
            log.info("%s may not touch tenant %r", principal.name, tenant)
            raise Forbidden(refusal(tenant))


def tenants_of(scope) -> set[str]:
    """Every tenant a request could select: each ``Fiware-Service`` and
    ``NGSILD-Tenant`` header and each ``service`` query parameter (Grafana),
    parsed as the routes parse them (``http.tenancy.selected_tenants``:
    ``%73ervice`` is ``service``) and
    lower-cased; the default tenant if none (or an empty one) is given.
    Checking all of them means no combination of selectors reaches a tenant
    the caller was not granted, whichever one a route prefers; the routes
    check the tenant they use once more (``http.tenancy``)."""
    return {normalise_tenant(v) for v in selected_tenants(scope)} or {""}


async def _refuse(send, exc: TsdbError) -> None:
    body = orjson.dumps(exc.body())
    headers = [(b"content-type", b"application/json"), (b"content-length", str(len(body)).encode())]
    if exc.status == 401:
        challenge = REALM if isinstance(exc, MissingCredential) else f'{REALM}, error="invalid_token"'
        headers.append((b"www-authenticate", challenge.encode()))
    elif exc.status == 403:
        headers.append((b"www-authenticate", f'{REALM}, error="insufficient_scope"'.encode()))
    await send({"type": "http.response.start", "status": exc.status, "headers": headers})
    await send({"type": "http.response.body", "body": body})
