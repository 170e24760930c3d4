"""OAuth2 bearer tokens: JWTs from Keyrock, Keycloak or any OpenID provider,
verified with PyJWT against a JWKS URL or a configured key.

The algorithm family follows the key: a JWKS or a PEM public key accepts
only asymmetric algorithms, a shared secret only HMAC ones, so a token can
never pick the algorithm that turns a public key into an HMAC secret.
Scopes and tenants come from configurable claims: OAuth2 ``scope`` (space
separated), Keyrock ``roles`` (objects with a ``name``), Keycloak
``realm_access.roles`` (strings).
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Iterable
from typing import Any
from urllib.parse import urlsplit

import httpx
import jwt
from cryptography.hazmat.primitives.serialization import load_pem_public_key
from starlette.concurrency import run_in_threadpool

from tsdb_service.core.errors import Unauthorized, Unavailable
from tsdb_service.security.principals import SCOPES, Principal, normalise_tenant

log = logging.getLogger(__name__)

ASYMMETRIC = ("RS256", "RS384", "RS512", "PS256", "PS384", "PS512", "ES256", "ES384", "ES512", "EdDSA")
HMAC = ("HS256", "HS384", "HS512")
LEEWAY_S = 30  # clock skew between us and the token issuer
JWKS_TIMEOUT_S = 5.0
JWKS_MIN_REFETCH_S = 30.0  # an unknown key id refetches at most this often
MIN_HMAC_KEY_BYTES = 32  # 256 bits, HS256's hash size (RFC 7518 3.2)


def looks_like_jwt(credential: str) -> bool:
    return credential.count(".") == 2


class JwksCache:
    """Signing keys fetched from a JWKS URL, kept ``ttl`` seconds. Fetched in
    a worker thread (never on the event loop), one fetch at a time, and at
    most every ``min_refetch`` seconds (a stream of tokens with made-up key
    ids cannot hammer the issuer); if a refetch fails the keys we have stay
    in use."""

    def __init__(self, url: str, ttl: float):
        self.url, self.ttl = url, ttl
        self.min_refetch = min(JWKS_MIN_REFETCH_S, ttl)
        self._keys: dict[str | None, jwt.PyJWK] = {}
        self._fetched_at = -float("inf")
        self._tried_at = -float("inf")
        self._lock = threading.Lock()

    async def key_for(self, kid: str | None) -> jwt.PyJWK:
        now = time.monotonic()
        key = self._find(kid)
        stale = now - self._fetched_at >= self.ttl
        if (key is None or stale) and now - self._tried_at >= self.min_refetch:
            await run_in_threadpool(self._refresh, now)
            key = self._find(kid)
        if key is not None:
            return key
        if not self._keys:
            raise Unavailable("cannot fetch the signing keys (JWKS) to verify the token; try again later")
        raise Unauthorized("the token is signed with a key the issuer does not publish")

    def _find(self, kid: str | None) -> jwt.PyJWK | None:
        if kid is None:
            return next(iter(self._keys.values())) if len(self._keys) == 1 else None
        return self._keys.get(kid)

    def _refresh(self, asked_at: float) -> None:
        with self._lock:
            if self._tried_at >= asked_at:  # another request fetched while we waited
                return
            self._tried_at = time.monotonic()
            try:
                response = httpx.get(self.url, timeout=JWKS_TIMEOUT_S)
                response.raise_for_status()
                keys = jwt.PyJWKSet.from_dict(response.json()).keys
            except (httpx.HTTPError, ValueError, jwt.PyJWTError) as exc:
                log.warning("cannot fetch JWKS from %s: %s", self.url, exc)
                return
            self._keys = {k.key_id: k for k in keys if k.public_key_use in (None, "sig")}
            self._fetched_at = self._tried_at


class TokenVerifier:
    """Verify a JWT and turn its claims into a ``Principal``."""

    def __init__(self, settings: Any):
        self.static_key, self.algorithms = check_token_settings(settings)
        self.jwks = JwksCache(settings.jwt_jwks_url, settings.jwt_jwks_cache_seconds) if settings.jwt_jwks_url else None
        self.audience = settings.jwt_audience or None
        self.issuer = settings.jwt_issuer or None
        self.scope_claims = [c.strip() for c in settings.jwt_scopes_claims.split(",") if c.strip()]
        self.scope_prefix = settings.jwt_scope_prefix
        self.tenants_claim = settings.jwt_tenants_claim.strip() or None
        if self.audience is None:
            log.warning("JWT audience not configured (TSDB_JWT_AUDIENCE): tokens for any client are accepted")

    @classmethod
    def from_settings(cls, settings: Any) -> TokenVerifier | None:
        return cls(settings) if settings.jwt_jwks_url or settings.jwt_key else None

    async def verify(self, token: str) -> Principal:
        try:
            kid = jwt.get_unverified_header(token).get("kid")
        except jwt.PyJWTError:
            raise Unauthorized("the bearer token is not a well-formed JWT") from None
        if self.jwks is not None:
            key = await self.jwks.key_for(kid)
        else:
            assert self.static_key is not None, "a verifier has a JWKS URL or a key (from_settings)"
            key = self.static_key
        try:
            claims = jwt.decode(
                token,
                key,
                algorithms=self.algorithms,
                audience=self.audience,
                issuer=self.issuer,
                leeway=LEEWAY_S,
                options={"require": ["exp"], "verify_aud": self.audience is not None},
            )
        except jwt.ExpiredSignatureError:
            raise Unauthorized("the token has expired") from None
        except jwt.PyJWTError as exc:
            raise Unauthorized(f"the token is not valid here: {exc}") from None
        return self._principal(claims)

    def _principal(self, claims: dict[str, Any]) -> Principal:
        granted = set()
        for claim in self.scope_claims:
            for value in _strings(_claim(claims, claim)):
                if value.startswith(self.scope_prefix) and value[len(self.scope_prefix) :] in SCOPES:
                    granted.add(value[len(self.scope_prefix) :])
        tenants = None
        if self.tenants_claim is not None:
            tenants = frozenset(normalise_tenant(t) for t in _strings(_claim(claims, self.tenants_claim)))
        name = str(claims.get("sub") or claims.get("azp") or claims.get("client_id") or "token")
        return Principal(f"jwt:{name[:64]}", frozenset(granted), tenants)


def _claim(claims: dict[str, Any], path: str) -> Any:
    value: Any = claims
    for part in path.split("."):
        if not isinstance(value, dict):
            return None
        value = value.get(part)
    return value


def _strings(value: Any) -> Iterable[str]:
    """A claim's values: a space- or comma-separated string, or a list of
    strings or of objects with a ``name`` (Keyrock roles and organizations)."""
    if isinstance(value, str):
        yield from value.replace(",", " ").split()
    elif isinstance(value, list):
        for item in value:
            if isinstance(item, str):
                yield item
            elif isinstance(item, dict) and isinstance(item.get("name"), str):
                yield item["name"]


# Settings that only mean something when tokens are verified.
_TOKEN_ONLY = ("jwt_algorithms", "jwt_audience", "jwt_issuer", "jwt_scope_prefix", "jwt_tenants_claim")


def check_token_settings(settings: Any) -> tuple[Any, list[str]]:
    """The configured key (None with a JWKS URL or no token source) and the
    allowed algorithms; ``ValueError`` naming the setting when the token
    settings cannot work: both sources, a JWKS URL that is not an http(s)
    URL, a key that is not a PEM public key, an algorithm that is unknown or
    of the other family, token settings without a token source (tokens would
    then not be checked at all). Reads nothing but the settings."""
    if settings.jwt_jwks_url and settings.jwt_key:
        raise ValueError("configure either TSDB_JWT_JWKS_URL or TSDB_JWT_KEY, not both")
    if settings.jwt_jwks_url:
        url = urlsplit(settings.jwt_jwks_url.strip())
        if url.scheme not in ("http", "https") or not url.hostname:
            raise ValueError(
                f"TSDB_JWT_JWKS_URL: {settings.jwt_jwks_url!r} is not an http(s) URL, "
                "e.g. https://keycloak/realms/fiware/protocol/openid-connect/certs"
            )
    elif not settings.jwt_key:
        given = [name for name in _TOKEN_ONLY if getattr(settings, name)]
        if given:
            flags = ", ".join(f"TSDB_{name.upper()}" for name in given)
            raise ValueError(f"{flags} set, but no token is verified: set TSDB_JWT_JWKS_URL or TSDB_JWT_KEY too")
    key = _load_key(settings.jwt_key) if settings.jwt_key else None
    return key, _algorithms(settings.jwt_algorithms, isinstance(key, bytes))


def _load_key(raw: str) -> Any:
    if raw.lstrip().startswith("-----BEGIN"):
        try:
            return load_pem_public_key(raw.strip().encode())
        except ValueError as exc:
            raise ValueError(f"TSDB_JWT_KEY is not a PEM public key: {exc}") from None
    secret = raw.encode("utf-8")
    if len(secret) < MIN_HMAC_KEY_BYTES:
        raise ValueError(
            f"TSDB_JWT_KEY: an HMAC secret must have at least {MIN_HMAC_KEY_BYTES} bytes (RFC 7518 3.2), "
            f"this one has {len(secret)}; a short one can be guessed offline from any token it signed "
            "(make one with: openssl rand -hex 32)"
        )
    return secret


def _algorithms(raw: str, symmetric: bool) -> list[str]:
    family = HMAC if symmetric else ASYMMETRIC
    chosen = [a.strip() for a in raw.split(",") if a.strip()] or list(family)
    unknown = [a for a in chosen if a not in HMAC + ASYMMETRIC]
    if unknown:
        raise ValueError(
            f"TSDB_JWT_ALGORITHMS: unknown algorithm {', '.join(unknown)}; choose from {', '.join(HMAC + ASYMMETRIC)}"
        )
    wrong = [a for a in chosen if a not in family]
    if wrong:
        kind = "a shared secret" if symmetric else "a public key or JWKS"
        raise ValueError(f"TSDB_JWT_ALGORITHMS: {', '.join(wrong)} cannot be used with {kind}; use {', '.join(family)}")
    return chosen
