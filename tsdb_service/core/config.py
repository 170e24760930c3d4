"""Settings from flags and ``TSDB_*`` environment variables.

Each setting is declared once, in its group (``StorageSettings``,
``HttpSettings``, ... ``LoggingSettings``); ``Settings`` inherits every
group, so ``settings.port``, ``--port`` and ``TSDB_PORT`` do not say which
group a setting is in, and the groups are the one source of the headings of
``serve --help`` and of the docs' settings table (docs/settings.md, checked
by tests/test_settings_groups.py).

``get_settings()`` is the one place the app reads configuration; tests and
the CLI override it by passing a ``Settings`` to ``create_app``.
"""

from __future__ import annotations

import re
from functools import lru_cache
from typing import Annotated, ClassVar
from urllib.parse import urlsplit

from pydantic import AfterValidator, BaseModel, Field, ValidationError, field_validator, model_validator
from pydantic_settings import BaseSettings, SettingsConfigDict

from tsdb_service.core.urlprefix import url_prefixes

MIB = 1024 * 1024
# DuckDB folds its WAL into the file once it is this big (its own default:
# 16 MiB). The commit that crosses it runs the checkpoint, and every
# notification queued behind that commit waits for it: about 60 ms at
# 16 MiB, 20-30 ms at 4 MiB, which took the ingest p99 at 64 connections
# from 56 to 33-38 ms at the same rate (benchmarks/README.md, "WAL
# checkpoint threshold").
WAL_CHECKPOINT_BYTES = 4 * MIB
LOG_LEVELS = ("critical", "error", "warning", "info", "debug", "trace")
POSTGRES_PREFIXES = ("postgresql://", "postgres://")
# "scheme:" at the start of --db; one letter is a Windows drive ("C:\\data"), not a scheme.
_SCHEME = re.compile(r"^([A-Za-z][A-Za-z0-9+.-]+):")


def _checked_prefixes(value: str) -> str:
    url_prefixes(value)  # raises ValueError
    return value


# A comma list of http(s) URL prefixes (TSDB_LD_CONTEXT_ALLOW, TSDB_SUBSCRIBE_BROKER_ALLOW), kept as given
# and compared by parts (core.urlprefix).
UrlPrefixes = Annotated[str, AfterValidator(_checked_prefixes)]


class SettingsGroup(BaseModel):
    """One group of settings: a title (a heading in ``serve --help`` and in
    the docs' settings table) and the fields it declares. ``Settings``
    inherits every group, so a field is ``settings.NAME``, ``--NAME`` and
    ``TSDB_NAME`` whatever group it is in."""

    title: ClassVar[str]
    about: ClassVar[str]


class StorageSettings(SettingsGroup):
    title = "Storage"
    about = "Where history is kept, and how the DuckDB file is maintained."

    db: str = Field(
        "./data/tsdb.duckdb",
        description="A DuckDB file path (embedded default) or a postgresql:// URL.",
    )
    writer_threads: int | None = Field(
        None,
        ge=1,
        le=16,
        description="Group-commit writer threads; default 1 on DuckDB (more only contend for the GIL), "
        "3 on PostgreSQL (commits wait on the network, so they overlap).",
    )
    compact_rows: int = Field(500_000, ge=1000, description="Move the hot table into the sorted one at this many rows.")
    major_compact_runs: int = Field(
        8, ge=1, description="Rewrite the sorted table after this many compactions into it."
    )
    wal_checkpoint_bytes: int = Field(
        WAL_CHECKPOINT_BYTES,
        ge=64 * 1024,
        description="DuckDB: fold the write-ahead log into the database file once it is this big "
        "(DuckDB's own default: 16 MiB).",
    )
    backup_dir: str = Field(
        "",
        description="Directory where POST /admin/backup (tsdb-service backup --url) writes DuckDB backups; "
        "a request names only a file in it. Empty: backups through the service are off.",
    )

    @field_validator("db")
    @classmethod
    def _db_is_a_file_or_a_postgres_url(cls, value: str) -> str:
        """Only two kinds of --db exist. Anything else (``postgress://``,
        ``mysql://``, ``postgresql:/x``) would otherwise become a DuckDB file
        of that name, silently taking data meant for another database."""
        return check_db(value)


class HttpSettings(SettingsGroup):
    title = "HTTP server"
    about = "Where the service listens, and what one connection or request may cost."

    host: str = Field("0.0.0.0", description="Address to bind, as QuantumLeap does.")
    port: int = Field(8668, ge=1, le=65535, description="QuantumLeap's port.")
    workers: int = Field(1, ge=1, description="uvicorn workers; PostgreSQL only.")
    ingest_processes: int = Field(
        1,
        ge=1,
        le=16,
        description="Processes that take HTTP notifications on one port, DuckDB only: the serving process and "
        "N-1 acceptors that parse and relay to it (docs: Architecture, 'Ingest processes'). 2 on 2 cores.",
    )
    max_connections: int = Field(
        4096,
        ge=1,
        description="Open connections per process; past it a new connection gets 503 and is closed.",
    )
    keep_alive_s: int = Field(5, ge=1, description="Close a kept-alive connection idle this long between requests.")
    header_timeout_s: float = Field(
        10.0,
        gt=0,
        description="Close a connection whose request headers are not complete this long after it "
        "opened (or after the request's first byte).",
    )
    body_timeout_s: float = Field(
        60.0,
        gt=0,
        description="Cut off a request whose body is not complete this long after its headers.",
    )
    max_header_bytes: int = Field(
        128 * 1024,
        ge=8 * 1024,
        le=16 * MIB,
        description="Largest request head (request line and header fields); larger: 431 and the "
        "connection is closed, counted while it arrives.",
    )
    max_body_bytes: int = Field(
        9 * MIB,
        ge=1024,
        description="Larger notifications and NGSI-LD temporal writes get 413 (notifications are kept in the "
        "rejected store). Orion sends notifications of up to 8 MB by default (its -outReqMsgMaxSize): "
        "the default leaves headroom above it.",
    )
    max_request_body_bytes: int = Field(
        1 * MIB,
        ge=1024,
        description="Largest body of any other request (queries, Grafana, layouts); larger: 413, "
        "refused while it is read.",
    )

    @field_validator("host")
    @classmethod
    def _host_not_empty(cls, value: str) -> str:
        if not value.strip():
            raise ValueError("is empty: give an address to bind, e.g. 0.0.0.0 or 127.0.0.1")
        return value.strip()


class IngestSettings(SettingsGroup):
    title = "Ingest"
    about = "How a notification becomes samples: which time each sample is stored at."

    time_index_paths: str = Field(
        "",
        description="Attributes whose samples are timed by a stamp inside their value, ahead of TimeInstant, "
        "observedAt and the arrival time: '[TYPE/]ATTR=PATH' rules separated by ',', e.g. "
        "'odom=header.stamp' (ROS header.stamp {sec, nanosec}, ISO 8601 or epoch numbers); empty: none.",
    )

    @field_validator("time_index_paths")
    @classmethod
    def _time_index_rules(cls, value: str) -> str:
        from tsdb_service.core.timepaths import parse_time_paths

        parse_time_paths(value)  # raises ValueError naming the rule
        return value


class IngestLogSettings(SettingsGroup):
    title = "Ingest log"
    about = "DuckDB: notifications are acknowledged once in this log, and applied to the database behind it."

    ingest_log: bool = Field(
        True,
        description="DuckDB: acknowledge notifications once they are in our own log next to the database "
        "(FILE.ingest-log/), and apply them to the database in bulk behind it. Off: each group waits for "
        "its own database commit. PostgreSQL has no ingest log (see the docs, Architecture).",
    )
    ingest_log_lag_bytes: int = Field(
        32 * 1024 * 1024,
        ge=1024 * 1024,
        description="DuckDB: how far (encoded bytes) the ingest log may run ahead of the database before "
        "ingest waits for it.",
    )


class CacheSettings(SettingsGroup):
    title = "Caches"
    about = "What reads keep in memory: the newest samples of each series, and aggregate partials."

    tail_cache_series: int = Field(
        8192, ge=0, description="DuckDB: sizes the in-memory tails (0: off); see tail_cache_samples."
    )
    tail_cache_rows: int = Field(128, ge=0, description="DuckDB: newest samples kept per cached series.")
    tail_cache_samples: int = Field(
        1_000_000, ge=0, description="DuckDB: samples kept in all tails (~200 bytes each), oldest-read out first."
    )
    agg_partials_hours: int = Field(
        100_000,
        ge=0,
        description="Series-hours of aggregate partials kept in memory for aggregated series "
        "(~400 bytes each, least recently aggregated out first; 0: off).",
    )


class ReadSettings(SettingsGroup):
    title = "Reads and budgets"
    about = (
        "How much one history query may select, read, render and take (past it: 422 QueryTooLarge), and all "
        "reads together (past it: they wait, then 503 ServerBusy)."
    )

    default_limit: int = Field(10_000, ge=1, description="Rows returned when no limit is given.")
    read_max_series: int = Field(
        50_000,
        ge=1,
        description="Series one request may select (per resolution step); more: 422 QueryTooLarge.",
    )
    read_max_rows: int = Field(
        500_000,
        ge=1,
        description="Samples and aggregate rows one request may read in all; more: 422 QueryTooLarge.",
    )
    read_max_response_bytes: int = Field(
        64 * MIB,
        ge=1024,
        description="Largest answer a read may render; larger: 422 QueryTooLarge.",
    )
    read_max_seconds: float = Field(
        20.0,
        gt=0,
        description="Wall time of one read, checked between its steps; past it: 422 QueryTooLarge.",
    )
    read_concurrency: int = Field(
        4,
        ge=2,
        le=1024,
        description="Reads of the database running at once, over all requests (about twice the cores); one "
        "tenant at most half (the others wait their turn, tenants served round-robin).",
    )
    read_rows_in_flight: int = Field(
        1_000_000,
        ge=2,
        description="Rows all reads together may hold, charged as they stream from the database; one tenant "
        "at most half (never less than one read's TSDB_READ_MAX_ROWS).",
    )
    read_queue_seconds: float = Field(
        10.0,
        gt=0,
        le=600,
        description="How long a read may wait for a free slot or room for its rows; past it: 503 ServerBusy "
        "with Retry-After.",
    )


class RejectedSettings(SettingsGroup):
    title = "Rejected store"
    about = "Notifications that were refused are kept, with their reason, within these bounds."

    rejected_body_max_bytes: int = Field(
        16 * MIB,
        ge=0,
        description="The rejected store keeps a rejected notification's body up to this many bytes "
        "(its full size is recorded, and that it was truncated).",
    )
    rejected_max_per_tenant: int = Field(
        1000,
        ge=1,
        description="Rejected notifications kept per tenant; the oldest are dropped first.",
    )
    rejected_max_bytes_per_tenant: int = Field(
        64 * MIB,
        ge=1024,
        description="Bytes of rejected bodies and headers kept per tenant; oldest dropped first "
        "(a tenant's newest rejection is always kept).",
    )
    rejected_max_total: int = Field(
        10_000,
        ge=1,
        description="Rejected notifications kept over all tenants together (refused tenant headers are "
        "chosen by the sender, so the per-tenant bounds alone multiply); the oldest are dropped first.",
    )
    rejected_max_total_bytes: int = Field(
        256 * MIB,
        ge=1024,
        description="Bytes of rejected bodies and headers kept over all tenants together; oldest dropped first "
        "(the newest rejection is always kept).",
    )
    rejected_max_age_days: float = Field(
        30.0,
        gt=0,
        description="Rejected notifications older than this are dropped (when the next is recorded).",
    )
    rejected_page_max_bytes: int = Field(
        8 * MIB,
        ge=1024,
        description="A rejected listing stops before this many bytes (at least one row) and points to the next page.",
    )


class SecuritySettings(SettingsGroup):
    title = "Security"
    about = "Authentication, CORS and the brokers POST /v2/subscribe may reach: off unless configured."

    # Plain strings, not lists: `serve` hands settings to workers as TSDB_*
    # variables via str(), and a comma list survives that round trip.
    api_keys: str = Field(
        "",
        repr=False,
        description="API keys as 'KEY:SCOPES[:TENANTS]' entries separated by ';' or spaces; "
        "SCOPES from read,write,admin,metrics; TENANTS a comma list ('-' is the default tenant), all if absent. "
        "Given as a flag, the keys show in ps and /proc to every local user: prefer --api-keys-file "
        "(digests only), or at least the variable.",
    )
    api_keys_file: str = Field(
        "", description="File of hashed API keys, one 'SHA256HEX SCOPES [TENANTS]' per line ('#' comments)."
    )
    api_key_header: str = Field("X-Api-Key", description="Header that carries an API key (besides Bearer).")
    jwt_jwks_url: str = Field("", description="JWKS URL of the OAuth2 server (Keycloak, ...): verify JWTs with it.")
    jwt_key: str = Field(
        "",
        repr=False,
        description="PEM public key, or the shared secret (Keyrock: the application's JWT secret; at least "
        "32 bytes). A secret given as a flag shows in ps: prefer the variable.",
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
    cors_origins: str = Field(
        "",
        description="Origins browsers may call us from, comma list ('*': any, refused without authentication "
        "unless TSDB_CORS_ALLOW_UNAUTHENTICATED); none by default.",
    )
    cors_allow_unauthenticated: bool = Field(
        False,
        description="Accept TSDB_CORS_ORIGINS=* with no authentication configured: any web page a visitor "
        "opens may then read, write and delete history.",
    )
    subscribe_broker_allow: UrlPrefixes = Field(
        "",
        description="URL prefixes of brokers POST /v2/subscribe may reach at any address, comma list (e.g. "
        "'http://orion:1026/'); any other orionUrl host must resolve to public addresses only.",
    )


class NgsiLdSettings(SettingsGroup):
    title = "NGSI-LD"
    about = "The temporal API's pages and answers, and the @context documents it loads."

    ngsild_default_limit: int = Field(100, ge=1, description="Entities per page when a temporal query gives no limit.")
    ngsild_max_limit: int = Field(1000, ge=1, description="Largest limit a temporal query may ask for.")
    ngsild_max_instances: int = Field(
        10_000,
        ge=1,
        description=(
            "Instances in one temporal answer; past it a V1.9.1 request gets 206 Partial Content,"
            " a TS 104 176 one (firstN/offsetN) a 200 page with links."
        ),
    )
    ngsild_contexts: str = Field(
        "", description="Local JSON-LD @context files: 'URL=path' pairs separated by ';' (served instead of fetching)."
    )
    ngsild_context_timeout: float = Field(
        2.0,
        gt=0,
        le=60,
        description="Seconds a request may spend loading remote @contexts in all: name resolution, "
        "connections, redirects and whole bodies.",
    )
    ld_context_allow: UrlPrefixes = Field(
        "",
        description="URL prefixes whose @contexts may be fetched from any address, comma list (e.g. "
        "'http://127.0.0.1:' for a conformance run on one machine); any other @context host must resolve "
        "to public addresses only.",
    )
    ld_context_offline: bool = Field(
        False,
        description="Never fetch a remote @context: only the built-in core context and the files of "
        "TSDB_NGSILD_CONTEXTS.",
    )
    ld_context_max_bytes: int = Field(
        1 * MIB, ge=1024, le=64 * MIB, description="Largest remote @context document, counted after decompression."
    )
    ld_context_cache_bytes: int = Field(
        32 * MIB,
        ge=0,
        description="Bytes of valid @context documents and term maps kept in memory (least recently used "
        "out first; documents are fresh for an hour and a fallback for a day).",
    )
    ld_inline_context_max_bytes: int = Field(
        64 * 1024, ge=1024, le=16 * MIB, description="Largest @context a request may carry inline (as JSON)."
    )


class MqttSettings(SettingsGroup):
    title = "MQTT"
    about = "Notifications from an MQTT broker as well as over HTTP: off unless --mqtt-url."

    mqtt_url: str = Field(
        "",
        description="Also take notifications from this MQTT broker: mqtt://HOST[:1883] or mqtts://HOST[:8883] "
        "(TLS); empty: no MQTT.",
    )
    mqtt_topics: str = Field(
        "",
        description="Topic filters to subscribe to, comma list (+ and # wildcards); default: from "
        "--mqtt-topic-template, e.g. tsdb/#.",
    )
    mqtt_topic_template: str = Field(
        "tsdb/${service}${servicePath}",
        description="How a topic names the tenant and service path, with Orion's mqttCustom macros "
        "${service} and ${servicePath} (any other ${...} matches one topic level); comma list, first match wins.",
    )
    mqtt_default_tenant: str = Field(
        "",
        description="Tenant of a message that names none (its topic matches no template and it carries no "
        "tenant header): a tenant, or '-' for the default tenant; empty: such a message is rejected (kept "
        "with its topic).",
    )
    mqtt_tenants: str = Field(
        "",
        description="Tenants each topic may write, as the tenants of an API key restrict HTTP: "
        "'FILTER=TENANT[,TENANT...]' entries separated by ';' (e.g. 'tsdb/alpha/#=alpha; tsdb/beta/#=beta'; "
        "'-' is the default tenant); a message for any other tenant is rejected. Empty: any tenant (only the "
        "broker's ACLs restrict who publishes what).",
    )
    mqtt_client_id: str = Field(
        "",
        description="MQTT client id: names our session on the broker, so it must stay the same across "
        "restarts and differ between replicas, and only we may use it (broker ACLs); default "
        "tsdb-service-HOSTNAME, which anyone can guess.",
    )
    mqtt_username: str = Field("", description="User name for the MQTT broker.")
    mqtt_password: str = Field(
        "",
        repr=False,
        description="Password for the MQTT broker. Given as a flag it shows in ps: prefer the variable.",
    )
    mqtt_ca_file: str = Field(
        "", description="mqtts://: CA certificates to verify the broker by (default: the system's)."
    )
    mqtt_cert_file: str = Field("", description="mqtts://: our client certificate (PEM), with --mqtt-key-file.")
    mqtt_key_file: str = Field("", description="mqtts://: the private key of --mqtt-cert-file (PEM).")
    mqtt_qos: int = Field(
        1,
        ge=0,
        le=1,
        description="QoS we subscribe with: 1, at least once (acknowledged once stored; a redelivery is not "
        "stored twice), or 0, at most once.",
    )
    mqtt_share_group: str = Field(
        "",
        description="Subscribe as a member of this MQTT 5 shared subscription ($share/GROUP/FILTER): "
        "replicas with the same group split the messages.",
    )
    mqtt_session_expiry_s: int = Field(
        7 * 86400,
        ge=0,
        le=0xFFFFFFFF,
        description="How long the broker keeps our session, with the messages it queues for us, while we "
        "are away (MQTT 5 Session Expiry Interval).",
    )
    mqtt_inflight: int = Field(
        64,
        ge=1,
        le=65535,
        description="Messages the broker may send us before we acknowledge the first (MQTT 5 Receive Maximum).",
    )
    mqtt_reconnect_max_s: int = Field(
        30,
        ge=1,
        le=3600,
        description="Longest wait between attempts to reach the broker again (the wait doubles from 1 s).",
    )

    @field_validator("mqtt_url")
    @classmethod
    def _mqtt_url(cls, value: str) -> str:
        return check_mqtt_url(value)

    @field_validator("mqtt_default_tenant")
    @classmethod
    def _mqtt_default_tenant(cls, value: str) -> str:
        tenant = value.strip()
        if tenant not in ("", "-") and not re.fullmatch(r"[A-Za-z0-9_]{1,50}", tenant):
            raise ValueError(f"{value[:60]!r} is not a tenant: 1 to 50 letters, digits or underscores, or '-'")
        return tenant

    @field_validator("mqtt_client_id", "mqtt_share_group")
    @classmethod
    def _mqtt_name(cls, value: str) -> str:
        name = value.strip()
        if any(c in name for c in "+#/") or len(name.encode()) > 256:
            raise ValueError(f"{value[:60]!r}: up to 256 bytes without '+', '#' or '/'")
        return name


class RetentionSettings(SettingsGroup):
    title = "Retention and rollups"
    about = "How long raw samples and each rollup level (minute, hour) are kept."

    retention: str = Field(
        "",
        description="How long raw samples and rollups are kept, per tenant and entity type: "
        "'*=365d,acme=30d,acme/Robot=raw:30d,minute:1y,hour:forever' (a bare duration is the raw level; "
        "or the same as a JSON object); empty: everything forever.",
    )
    rollups: bool = Field(
        False,
        description="Deprecated, no effect: minute and hour rollups are always kept up to date on ingest "
        "(their retention is in --retention).",
    )
    rollup_retention: str = Field(
        "",
        description="Deprecated: rules for both rollup levels, as minute: and hour: in --retention "
        "(which it is merged into).",
    )
    retention_interval: float = Field(300.0, gt=0, description="Seconds between retention passes.")
    retention_batch_rows: int = Field(
        50_000,
        ge=1,
        description="Rows deleted per batch and table, each batch its own short transaction.",
    )
    retention_pause: float = Field(0.05, ge=0, description="Seconds to pause between retention batches.")

    @field_validator("retention", "rollup_retention")
    @classmethod
    def _retention_spec(cls, value: str, info) -> str:
        from tsdb_service.core.retention_policy import RetentionPolicy

        RetentionPolicy.parse(value, setting="TSDB_" + info.field_name.upper())  # raises ValueError
        return value

    @model_validator(mode="after")
    def _levels_in_order(self):
        self.retention_policy()  # raises ValueError: the merged policy keeps its levels in order
        return self

    def retention_policy(self):
        """The policy ``--retention`` and the deprecated ``--rollup-retention`` make together."""
        from tsdb_service.core.retention_policy import RetentionPolicy

        policy = RetentionPolicy.parse(self.retention, "TSDB_RETENTION")
        if self.rollup_retention.strip():
            rollups = RetentionPolicy.parse(self.rollup_retention, "TSDB_ROLLUP_RETENTION")
            policy = policy.with_rollup_rules(rollups, "TSDB_ROLLUP_RETENTION")
        return policy


class LoggingSettings(SettingsGroup):
    title = "Logging"
    about = "What the service writes to its log."

    log_level: str = Field("info", description=f"One of {', '.join(LOG_LEVELS)}.")
    access_log: bool = Field(False, description="Log every request (uvicorn's access log).")

    @field_validator("log_level")
    @classmethod
    def _known_log_level(cls, value: str) -> str:
        level = value.strip().lower()
        if level not in LOG_LEVELS:
            raise ValueError(f"unknown log level {value!r}: choose from {', '.join(LOG_LEVELS)}")
        return level


class Settings(
    StorageSettings,
    HttpSettings,
    IngestSettings,
    IngestLogSettings,
    CacheSettings,
    ReadSettings,
    RejectedSettings,
    SecuritySettings,
    NgsiLdSettings,
    MqttSettings,
    RetentionSettings,
    LoggingSettings,
    BaseSettings,
):
    """Every setting, from keyword arguments (the CLI's flags) over ``TSDB_*``
    variables over the defaults; each declared in its group above."""

    model_config = SettingsConfigDict(env_prefix="TSDB_", extra="ignore")

    @property
    def backend(self) -> str:
        return "postgresql" if self.db.startswith(("postgresql://", "postgres://")) else "duckdb"


# The groups in the order of Settings' bases: the order `serve --help` and the
# docs' settings table show them in.
SETTING_GROUPS: tuple[type[SettingsGroup], ...] = tuple(
    base for base in Settings.__bases__ if issubclass(base, SettingsGroup)
)


def setting_groups() -> tuple[tuple[type[SettingsGroup], tuple[str, ...]], ...]:
    """Each group with its settings' names, in declaration order."""
    return tuple((group, tuple(group.model_fields)) for group in SETTING_GROUPS)


def check_db(value: str) -> str:
    """A DuckDB file path or a ``postgresql://`` / ``postgres://`` URL; else ValueError."""
    db = value.strip()
    if not db:
        raise ValueError("is empty: give a DuckDB file path or a postgresql:// URL")
    if db.startswith(POSTGRES_PREFIXES):
        return db
    match = _SCHEME.match(db)
    if match is None:
        return db
    scheme = match[1]
    if scheme.lower() in ("postgresql", "postgres"):
        raise ValueError(f"{db!r} is not a PostgreSQL URL: write postgresql://user@host:port/database")
    if db[match.end() :].startswith("//"):
        raise ValueError(
            f"{db!r}: unsupported scheme {scheme}:// (only postgresql:// or postgres:// URLs and DuckDB file paths)"
        )
    raise ValueError(
        f"{db!r} starts like a URL ({scheme}:): give a postgresql:// URL or a DuckDB file path "
        f"(./{db} for a file name with a colon)"
    )


MQTT_SCHEMES = {"mqtt": 1883, "mqtts": 8883}


def check_mqtt_url(value: str) -> str:
    """Empty, or ``mqtt://host[:port]`` / ``mqtts://host[:port]``; else ValueError.
    Credentials go in their own settings, not in the URL (which logs show)."""
    url = value.strip()
    if not url:
        return ""
    parts = urlsplit(url)
    if parts.scheme not in MQTT_SCHEMES:
        raise ValueError(f"{url[:80]!r}: give mqtt://host:1883 or mqtts://host:8883")
    if "@" in parts.netloc:
        raise ValueError("holds credentials: give them as --mqtt-username and TSDB_MQTT_PASSWORD instead")
    try:
        port = parts.port
    except ValueError:
        raise ValueError(f"{url[:80]!r}: the port must be a number from 1 to 65535") from None
    if not parts.hostname or port == 0:
        raise ValueError(f"{url[:80]!r}: give a host (and a port from 1 to 65535), e.g. mqtt://broker:1883")
    if parts.path not in ("", "/") or parts.query or parts.fragment:
        raise ValueError(f"{url[:80]!r}: only a host and port; topics go in --mqtt-topics")
    return url


class SettingsError(ValueError):
    """A setting is invalid; the message is one line naming the flag and its variable."""


def flag_named(message: str) -> str:
    """``TSDB_API_KEYS entry 1: ...`` as ``--api-keys (TSDB_API_KEYS) entry 1: ...``: a
    message that opens with a variable names its flag too, as every setting's error does."""
    variable = re.match(r"TSDB_[A-Z_]*[A-Z]", message)
    if variable is None or variable[0].removeprefix("TSDB_").lower() not in Settings.model_fields:
        return message
    flag = "--" + variable[0].removeprefix("TSDB_").lower().replace("_", "-")
    return f"{flag} ({variable[0]}){message[variable.end() :]}"


def load_settings(**overrides) -> Settings:
    """``Settings`` from ``overrides`` and ``TSDB_*`` variables, or one ``SettingsError``
    line per problem joined with "; " (pydantic's report spans many lines)."""
    try:
        return Settings(**overrides)
    except ValidationError as exc:
        raise SettingsError(describe(exc)) from None


def describe(exc: ValidationError) -> str:
    """pydantic's errors as ``--port (TSDB_PORT): must be at most 65535, got 99999``."""
    problems = []
    for error in exc.errors():
        name = str(error["loc"][0]) if error["loc"] else "settings"
        message = error["msg"]
        for prefix in ("Value error, ", "Input should be "):
            if message.startswith(prefix):
                message = ("must be " if prefix == "Input should be " else "") + message[len(prefix) :]
        flag = f"--{name.replace('_', '-')} (TSDB_{name.upper()})"
        problems.append(
            f"{flag}: {message}, got {error['input']!r}" if error["type"] != "value_error" else f"{flag}: {message}"
        )
    return "; ".join(problems)


@lru_cache(maxsize=1)
def get_settings() -> Settings:
    return Settings()
