"""Who is calling and what they may do: scopes, tenant restrictions, and the
scope each request needs.

Scopes are ``read``, ``write`` and ``admin``. ``admin`` implies the other two;
``write`` does not imply ``read``, so the key an Orion subscription carries
cannot be used to read the history it writes.
"""

from __future__ import annotations

from dataclasses import dataclass

from tsdb_service.core.errors import TsdbError

READ, WRITE, ADMIN = "read", "write", "admin"
SCOPES = frozenset({READ, WRITE, ADMIN})
DEFAULT_TENANT_TOKEN = "-"  # stands for "" (no Fiware-Service) in tenant lists

# Reads that travel as POST (a query in a body) need read, not write.
_READ_POSTS = ("/grafana/", "/v2/op/query", "/ngsi-ld/v1/temporal/entityOperations/query")  # queries in a body


class Unauthorized(TsdbError):
    """No credential, or one we cannot verify: the client should authenticate."""

    status = 401
    error = "Unauthorized"


class MissingCredential(Unauthorized):
    """No credential at all (the challenge then carries no error code)."""


class Forbidden(TsdbError):
    """A verified caller asking for more than it was granted."""

    status = 403
    error = "Forbidden"


@dataclass(frozen=True, slots=True)
class Principal:
    """A verified caller: a name for logs, its scopes, and the tenants it may
    touch (``None``: every tenant)."""

    name: str
    scopes: frozenset[str]
    tenants: frozenset[str] | None = None

    def may(self, scope: str) -> bool:
        return ADMIN in self.scopes or scope in self.scopes

    def may_touch(self, tenant: str) -> bool:
        return self.tenants is None or tenant in self.tenants


def required_scope(method: str, path: str) -> str:
    """The scope a request needs: deletes, the rejected store (which holds
    raw request bodies) and ``POST /v2/subscribe`` (which makes this service
    call a URL the client names) need admin, changes need write, everything
    else read."""
    path = path.rstrip("/") or "/"
    if method == "DELETE" or path == "/v2/notify/rejected" or path.startswith("/v2/notify/rejected/"):
        return ADMIN
    if method == "POST" and path == "/v2/subscribe":
        return ADMIN
    if method in ("GET", "HEAD", "OPTIONS"):
        return READ
    if method == "POST" and path.startswith(_READ_POSTS):
        return READ
    return WRITE


def parse_scopes(raw: str, where: str) -> frozenset[str]:
    scopes = frozenset(s.strip().lower() for s in raw.split(",") if s.strip())
    if not scopes or not scopes <= SCOPES:
        raise ValueError(f"{where}: scopes must be a comma list of read, write, admin; got {raw!r}")
    return scopes


def parse_tenants(raw: str | None) -> frozenset[str] | None:
    """A comma list of tenants, lower-cased as Orion stores them; ``-`` is the
    default tenant; ``None`` (no list at all) means every tenant."""
    if raw is None:
        return None
    return frozenset(normalise_tenant(t) for t in raw.split(",") if t.strip())


def normalise_tenant(raw: str) -> str:
    raw = raw.strip().lower()
    return "" if raw == DEFAULT_TENANT_TOKEN else raw
