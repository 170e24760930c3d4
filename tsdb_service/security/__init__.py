"""Who may do what: API keys and OAuth2 bearer tokens with scopes and
tenants, and CORS for browser clients (``core.credentials`` keeps credentials
out of storage).

Everything is off unless configured (see ``Settings``' security block and
docs/security.md): ``protect`` then returns the app as is.
"""

from __future__ import annotations

from starlette.middleware.cors import CORSMiddleware

from tsdb_service.core.errors import Forbidden, Unauthorized
from tsdb_service.http.responses import EXPOSED_HEADERS
from tsdb_service.security.guard import Guard
from tsdb_service.security.keys import KeyRing
from tsdb_service.security.principals import ADMIN, METRICS, READ, WRITE, Principal, required_scope
from tsdb_service.security.tokens import TokenVerifier, check_token_settings

__all__ = [
    "ADMIN",
    "METRICS",
    "READ",
    "WRITE",
    "Forbidden",
    "Principal",
    "Unauthorized",
    "authenticates",
    "check",
    "protect",
    "required_scope",
]

CORS_MAX_AGE_S = 600


def protect(app, settings):
    """Wrap the ASGI ``app`` in what the settings ask for: the guard when any
    credential is configured, CORS (outermost, so preflights need no
    credential and refusals still reach the browser) when origins are.
    ValueError for settings that would leave the service open (see ``check``)."""
    keys, tokens = _credentials(settings)
    origins = [o.strip().rstrip("/") for o in settings.cors_origins.split(",") if o.strip()]
    if "*" in origins and keys is None and tokens is None and not settings.cors_allow_unauthenticated:
        raise ValueError(
            "TSDB_CORS_ORIGINS is * without authentication, which lets any web page its visitors open read, write and "
            "delete this service's history: configure keys or tokens (TSDB_API_KEYS_FILE, TSDB_JWT_*), name "
            "the origins, or set TSDB_CORS_ALLOW_UNAUTHENTICATED=true if that is really meant"
        )
    if keys is not None or tokens is not None:
        app = Guard(app, keys, tokens, settings.api_key_header)
    if origins:
        app = CORSMiddleware(
            app,
            allow_origins=origins,
            allow_methods=["GET", "HEAD", "POST", "PUT", "DELETE"],
            allow_headers=["*"],
            expose_headers=["X-Request-Id", "WWW-Authenticate", *EXPOSED_HEADERS],
            max_age=CORS_MAX_AGE_S,
        )
    return app


def authenticates(settings) -> bool:
    """Whether every request but the open paths needs a credential: some API
    key or token setting is configured, so ``protect`` installs the guard."""
    keys, tokens = _credentials(settings)
    return keys is not None or tokens is not None


def _credentials(settings) -> tuple[KeyRing | None, TokenVerifier | None]:
    return KeyRing.from_settings(settings.api_keys, settings.api_keys_file), TokenVerifier.from_settings(settings)


def check(settings) -> None:
    """The security settings, checked before a server starts (``serve``,
    before it creates anything): ValueError naming the setting. Keys, key
    file and token settings, then whatever ``protect`` would refuse (a weak
    HMAC secret, an open CORS without authentication). Nothing is fetched."""
    KeyRing.from_settings(settings.api_keys, settings.api_keys_file)
    check_token_settings(settings)
    protect(None, settings)
