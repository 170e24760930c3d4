"""The MQTT consumer's settings, read once from ``Settings`` and checked.

``MqttConfig.from_settings`` raises ``ValueError`` with a message that opens
with the setting's variable (``TSDB_MQTT_TOPICS ...``), which ``serve``
turns into one ``error:`` line naming the flag too (``cli.main.check_serve``).
"""

from __future__ import annotations

import os
import socket
from dataclasses import dataclass
from urllib.parse import urlsplit

from tsdb_service.core.config import MQTT_SCHEMES, Settings
from tsdb_service.ingest.mqtt.topics import TenantRule, TopicTemplate, check_filter, parse_templates, parse_tenant_rules

MIB = 1024 * 1024
# What the broker may send beyond a notification's own bytes: the topic and
# the packet's head (MQTT 5 Maximum Packet Size; larger ones it drops).
PACKET_OVERHEAD = 64 * 1024 + 1024
MAX_PACKET = 268_435_455  # the largest MQTT packet
# Messages received and not yet stored, in bytes; one message always fits.
BUFFER_BYTES = 64 * MIB
# Deliveries remembered per client id, in receive maximums: a redelivery is
# always of a message among the last receive-maximum we received (see
# docs/mqtt.md, "Delivery guarantees").
WINDOW_FACTOR = 4


# Settings that mean nothing without TSDB_MQTT_URL: given alone, a mistake.
_NEED_URL = ("mqtt_topics", "mqtt_share_group", "mqtt_username", "mqtt_password", "mqtt_ca_file", "mqtt_tenants")


@dataclass(frozen=True, slots=True)
class MqttConfig:
    url: str  # as given, for messages: never holds credentials (Settings refuses them)
    host: str
    port: int
    tls: bool
    client_id: str
    filters: tuple[str, ...]  # as subscribed: with the $share/GROUP/ prefix
    templates: tuple[TopicTemplate, ...]
    default_tenant: str | None  # None: a message naming no tenant is rejected; "": the default tenant
    qos: int
    session_expiry_s: int
    inflight: int
    reconnect_max_s: int
    max_payload_bytes: int
    rejected_body_max_bytes: int
    api_key_header: str
    username: str = ""
    password: str = ""
    ca_file: str = ""
    cert_file: str = ""
    key_file: str = ""
    tenant_rules: tuple[TenantRule, ...] = ()  # TSDB_MQTT_TENANTS; empty: any tenant
    client_id_is_default: bool = False  # ``tsdb-service-HOSTNAME``: guessable (``serve`` warns without credentials)
    time_index_paths: str = ""  # TSDB_TIME_INDEX_PATHS, as for HTTP notifications

    @property
    def window(self) -> int:
        """Deliveries remembered per client id (in memory and in the database)."""
        return WINDOW_FACTOR * self.inflight

    @property
    def max_packet_bytes(self) -> int:
        return min(self.max_payload_bytes + PACKET_OVERHEAD, MAX_PACKET)

    @classmethod
    def from_settings(cls, settings: Settings) -> MqttConfig | None:
        """None when MQTT is off (no ``--mqtt-url``); ValueError on a bad setting."""
        if not settings.mqtt_url:
            for name in _NEED_URL:
                if getattr(settings, name):
                    raise ValueError(f"TSDB_{name.upper()} is set but TSDB_MQTT_URL is not: give the broker's URL")
            return None
        parts = urlsplit(settings.mqtt_url)
        tls = parts.scheme == "mqtts"
        try:
            templates = parse_templates(settings.mqtt_topic_template)
        except ValueError as exc:
            raise ValueError(f"TSDB_MQTT_TOPIC_TEMPLATE: {exc}") from None
        given = [item.strip() for item in settings.mqtt_topics.split(",") if item.strip()]
        try:
            filters = tuple(dict.fromkeys(check_filter(f) for f in given))
        except ValueError as exc:
            raise ValueError(f"TSDB_MQTT_TOPICS: {exc}") from None
        if not filters:
            filters = tuple(dict.fromkeys(t.filter for t in templates))
        if not filters:
            raise ValueError("TSDB_MQTT_TOPICS is empty and so is TSDB_MQTT_TOPIC_TEMPLATE: nothing to subscribe to")
        try:
            tenant_rules = parse_tenant_rules(settings.mqtt_tenants)
        except ValueError as exc:
            raise ValueError(f"TSDB_MQTT_TENANTS: {exc}") from None
        if settings.mqtt_share_group:
            filters = tuple(f"$share/{settings.mqtt_share_group}/{f}" for f in filters)
        _check_credentials(settings, tls)
        default = settings.mqtt_default_tenant
        return cls(
            url=settings.mqtt_url,
            host=parts.hostname or "",
            port=parts.port or MQTT_SCHEMES[parts.scheme],
            tls=tls,
            client_id=settings.mqtt_client_id or default_client_id(),
            filters=filters,
            templates=templates,
            default_tenant=None if not default else "" if default == "-" else default.lower(),
            qos=settings.mqtt_qos,
            session_expiry_s=settings.mqtt_session_expiry_s,
            inflight=settings.mqtt_inflight,
            reconnect_max_s=settings.mqtt_reconnect_max_s,
            max_payload_bytes=settings.max_body_bytes,
            rejected_body_max_bytes=settings.rejected_body_max_bytes,
            api_key_header=settings.api_key_header,
            username=settings.mqtt_username,
            password=settings.mqtt_password,
            ca_file=settings.mqtt_ca_file,
            cert_file=settings.mqtt_cert_file,
            key_file=settings.mqtt_key_file,
            tenant_rules=tenant_rules,
            client_id_is_default=not settings.mqtt_client_id,
            time_index_paths=settings.time_index_paths,
        )


def _check_credentials(settings: Settings, tls: bool) -> None:
    if settings.mqtt_password and not settings.mqtt_username:
        raise ValueError("TSDB_MQTT_PASSWORD is set without TSDB_MQTT_USERNAME")
    files = {"mqtt_ca_file": settings.mqtt_ca_file, "mqtt_cert_file": settings.mqtt_cert_file}
    files["mqtt_key_file"] = settings.mqtt_key_file
    for name, path in files.items():
        if not path:
            continue
        if not tls:
            raise ValueError(f"TSDB_{name.upper()} needs an mqtts:// TSDB_MQTT_URL (TLS)")
        if not os.path.isfile(path) or not os.access(path, os.R_OK):
            raise ValueError(f"TSDB_{name.upper()} {path!r} is not a readable file")
    if bool(settings.mqtt_cert_file) != bool(settings.mqtt_key_file):
        raise ValueError("TSDB_MQTT_CERT_FILE and TSDB_MQTT_KEY_FILE go together: a client certificate and its key")


def default_client_id() -> str:
    """``tsdb-service-HOSTNAME``: stable across restarts of one machine or
    container, different between replicas on different hosts."""
    host = "".join(c if c.isalnum() or c in "-_." else "-" for c in socket.gethostname())[:200]
    return f"tsdb-service-{host or 'localhost'}"
