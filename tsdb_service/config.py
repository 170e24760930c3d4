"""Settings from flags and ``TSDB_*`` environment variables.

``get_settings()`` is the one place the app reads configuration; tests and
the CLI override it by passing a ``Settings`` to ``create_app``.
"""

from __future__ import annotations

from functools import lru_cache

from pydantic import Field
from pydantic_settings import BaseSettings, SettingsConfigDict

MIB = 1024 * 1024


class Settings(BaseSettings):
    model_config = SettingsConfigDict(env_prefix="TSDB_", extra="ignore")

    db: str = Field(
        "./data/tsdb.duckdb",
        description="A DuckDB file path (embedded default) or a postgresql:// URL.",
    )
    host: str = Field("0.0.0.0", description="Address to bind, as QuantumLeap does.")
    port: int = Field(8668, description="QuantumLeap's port.")
    workers: int = Field(1, ge=1, description="uvicorn workers; PostgreSQL only.")
    max_body_bytes: int = Field(
        9 * MIB, ge=1024,
        description="Larger notifications get 413 (and are kept in the rejected store). Orion sends "
        "notifications of up to 8 MB by default (its -outReqMsgMaxSize): the default leaves headroom above it.",
    )
    rejected_body_max_bytes: int = Field(
        16 * MIB, ge=0,
        description="The rejected store keeps a rejected notification's body up to this many bytes "
        "(its full size is recorded, and that it was truncated).",
    )
    default_limit: int = Field(10_000, ge=1, description="Rows returned when no limit is given.")
    compact_rows: int = Field(
        500_000, ge=1000, description="Move the hot table into the sorted one at this many rows."
    )
    major_compact_runs: int = Field(
        8, ge=1, description="Rewrite the sorted table after this many compactions into it."
    )
    writer_threads: int | None = Field(
        None, ge=1, le=16,
        description="Group-commit writer threads; default 1 on DuckDB (more only contend for the GIL), "
        "3 on PostgreSQL (commits wait on the network, so they overlap).",
    )
    tail_cache_series: int = Field(
        8192, ge=0, description="DuckDB: sizes the in-memory tails (0: off); see tail_cache_samples."
    )
    tail_cache_rows: int = Field(128, ge=0, description="DuckDB: newest samples kept per cached series.")
    tail_cache_samples: int = Field(
        1_000_000, ge=0, description="DuckDB: samples kept in all tails (~200 bytes each), oldest-read out first."
    )
    log_level: str = "info"
    access_log: bool = False

    # -- security: everything off unless configured (see README "Security") --
    # Plain strings, not lists: `serve` hands settings to workers as TSDB_*
    # variables via str(), and a comma list survives that round trip.
    api_keys: str = Field(
        "", repr=False,
        description="API keys as 'KEY:SCOPES[:TENANTS]' entries separated by ';' or spaces; "
        "SCOPES from read,write,admin; TENANTS a comma list ('-' is the default tenant), all if absent.",
    )
    api_keys_file: str = Field(
        "", description="File of hashed API keys, one 'SHA256HEX SCOPES [TENANTS]' per line ('#' comments)."
    )
    api_key_header: str = Field("X-Api-Key", description="Header that carries an API key (besides Bearer).")
    jwt_jwks_url: str = Field("", description="JWKS URL of the OAuth2 server (Keycloak, ...): verify JWTs with it.")
    jwt_key: str = Field(
        "", repr=False, description="PEM public key, or the shared secret (Keyrock: the application's JWT secret)."
    )
    jwt_algorithms: str = Field("", description="Allowed JWT algorithms; default: RS/PS/ES/EdDSA, or HS for a secret.")
    jwt_audience: str = Field("", description="Required 'aud' of tokens (recommended).")
    jwt_issuer: str = Field("", description="Required 'iss' of tokens (recommended).")
    jwt_scopes_claims: str = Field(
        "scope,roles,realm_access.roles",
        description="Claims (dotted paths) whose values grant scopes: OAuth2 'scope', Keyrock 'roles', "
        "Keycloak 'realm_access.roles'.",
    )
    jwt_scope_prefix: str = Field("", description="Only claim values with this prefix count (e.g. 'tsdb:').")
    jwt_tenants_claim: str = Field("", description="Claim listing the tenants a token may touch; empty: all.")
    jwt_jwks_cache_seconds: int = Field(300, ge=1, le=86_400, description="How long fetched JWKS keys are kept.")
    # -- NGSI-LD temporal API reads (see README "NGSI-LD temporal API") --
    ngsild_default_limit: int = Field(100, ge=1, description="Entities per page when a temporal query gives no limit.")
    ngsild_max_limit: int = Field(1000, ge=1, description="Largest limit a temporal query may ask for.")
    ngsild_max_instances: int = Field(
        10_000, ge=1, description="Instances in one temporal answer; past it the answer is 206 Partial Content."
    )
    ngsild_contexts: str = Field(
        "", description="Local JSON-LD @context files: 'URL=path' pairs separated by ';' (served instead of fetching)."
    )
    ngsild_context_timeout: float = Field(2.0, gt=0, le=60, description="Seconds to wait for a remote @context.")
    cors_origins: str = Field(
        "", description="Origins browsers may call us from, comma list ('*': any); none by default."
    )

    @property
    def backend(self) -> str:
        return "postgresql" if self.db.startswith(("postgresql://", "postgres://")) else "duckdb"


@lru_cache(maxsize=1)
def get_settings() -> Settings:
    return Settings()
