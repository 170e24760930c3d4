"""A real OAuth2 issuer stand-in for tests: RSA keys, tokens signed with
them, and their JWKS served over HTTP from a local thread.

    with Issuer() as issuer:
        token = issuer.token(scope="read write", aud="tsdb")
        settings = {"jwt_jwks_url": issuer.jwks_url, ...}
"""

from __future__ import annotations

import json
import time
import uuid
from http.server import BaseHTTPRequestHandler

import jwt
from cryptography.hazmat.primitives.asymmetric import rsa

from .local_http import LocalServer

__all__ = ["Issuer"]

ISSUER = "http://issuer.test/realms/fiware"


class Issuer(LocalServer):
    """Signs tokens with its current key; publishes the keys in ``published``."""

    def __init__(self):
        self.keys: dict[str, rsa.RSAPrivateKey] = {}
        self.published: list[str] = []
        self.fetches = 0
        self.available = True
        self.kid = self.rotate()
        super().__init__()

    @property
    def jwks_url(self) -> str:
        return f"{self.url}/certs"

    def rotate(self, publish: bool = True) -> str:
        """A new signing key (published unless told otherwise); its kid."""
        kid = uuid.uuid4().hex[:12]
        self.keys[kid] = rsa.generate_private_key(public_exponent=65537, key_size=2048)
        if publish:
            self.published.append(kid)
        self.kid = kid
        return kid

    def jwks(self) -> dict:
        keys = []
        for kid in self.published:
            jwk = json.loads(jwt.algorithms.RSAAlgorithm.to_jwk(self.keys[kid].public_key()))
            keys.append({**jwk, "kid": kid, "use": "sig", "alg": "RS256"})
        return {"keys": keys}

    def token(self, *, kid: str | None = None, lifetime: float = 300, headers: dict | None = None, **claims) -> str:
        now = int(time.time())
        payload = {"iss": ISSUER, "sub": "user-1", "iat": now, "exp": now + int(lifetime), **claims}
        kid = kid or self.kid
        return jwt.encode(payload, self.keys[kid], algorithm="RS256", headers={"kid": kid, **(headers or {})})

    def _handler(self):
        issuer = self

        class Handler(BaseHTTPRequestHandler):
            def do_GET(self):
                issuer.fetches += 1
                if not issuer.available or self.path != "/certs":
                    self.send_error(503 if not issuer.available else 404)
                    return
                body = json.dumps(issuer.jwks()).encode()
                self.send_response(200)
                self.send_header("Content-Type", "application/json")
                self.send_header("Content-Length", str(len(body)))
                self.end_headers()
                self.wfile.write(body)

            def log_message(self, *_args):
                pass

        return Handler
