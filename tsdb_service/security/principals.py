"""Who is calling and what they may do: scopes, tenant restrictions, and the
scope each request needs.

Scopes are ``read``, ``write``, ``admin`` and ``metrics``. ``admin`` implies
the others; ``write`` does not imply ``read``, so the key an Orion
subscription carries cannot be used to read the history it writes.
``metrics`` is what ``/metrics`` needs (its labels name every tenant): a
Prometheus scraper's key, or any ``read`` credential not restricted to tenants.
The errors (``Unauthorized``, ``MissingCredential``, ``Forbidden``) are in
``core.errors``, so routes can refuse too.
"""

from __future__ import annotations

from dataclasses import dataclass

READ, WRITE, ADMIN, METRICS = "read", "write", "admin", "metrics"
SCOPES = frozenset({READ, WRITE, ADMIN, METRICS})
DEFAULT_TENANT_TOKEN = "-"  # stands for "" (no Fiware-Service) in tenant lists

# Reads that travel as POST (a query in a body) need read, not write.
_READ_POSTS = ("/grafana/", "/v2/op/query", "/ngsi-ld/v1/temporal/entityOperations/query")  # queries in a body
METRICS_PATH = "/metrics"
ADMIN_PATH = "/admin"  # operations on the whole store (backups)


@dataclass(frozen=True, slots=True)
class Principal:
    """A verified caller: a name for logs, its scopes, and the tenants it may
    touch (``None``: every tenant)."""

    name: str
    scopes: frozenset[str]
    tenants: frozenset[str] | None = None

    def may(self, scope: str) -> bool:
        """``admin`` implies every scope; ``metrics`` (whose labels name every
        tenant) is also implied by ``read`` over every tenant."""
        if ADMIN in self.scopes or scope in self.scopes:
            return True
        return scope == METRICS and READ in self.scopes and self.tenants is None

    def may_touch(self, tenant: str) -> bool:
        return self.tenants is None or tenant in self.tenants


def required_scope(method: str, path: str) -> str:
    """The scope a request needs: changing or deleting stored history
    (``DELETE``, and ``PATCH`` of an NGSI-LD instance), the rejected store
    (which holds raw request bodies), ``POST /v2/subscribe`` (which makes
    this service call a URL the client names) and ``/admin/`` (backups) need
    admin; ``/metrics`` needs metrics; adding data needs write, everything
    else read."""
    path = path.rstrip("/") or "/"
    if method in ("DELETE", "PATCH") or path == "/v2/notify/rejected" or path.startswith("/v2/notify/rejected/"):
        return ADMIN
    if path == ADMIN_PATH or path.startswith(ADMIN_PATH + "/"):
        return ADMIN
    if path == METRICS_PATH:
        return METRICS
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
        raise ValueError(f"{where}: scopes must be a comma list of read, write, admin, metrics; got {raw!r}")
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
