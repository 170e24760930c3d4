"""One MQTT message into samples, or into the rejected store, with its topic.

What a broker publishes, by who publishes it:

* **Orion** (``notification.mqtt`` / ``mqttCustom``): the bare notification
  body, as ``POST /v2/notify`` would get it, but with no headers (MQTT 3.1.1
  has none): the tenant and service path are the topic's (``topics``), and
  the format is read from the body's shape.
* **Orion-LD, Stellio, Scorpio**: ``{"metadata": {HEADERS}, "body":
  {NOTIFICATION}}``, the HTTP headers they would have sent as ``metadata``
  (``Ngsild-Tenant``, ``Ngsild-Attribute-Format``, ``Content-Type``, a
  ``receiverInfo`` ``Fiware-ServicePath``...).
* **Anyone on MQTT 5**: user properties are headers too (and the Content
  Type property ``Content-Type``).

Then the same parser as ``POST /v2/notify`` (``parse.parse_document``) reads
every format it reads. The tenant: a tenant header (``Fiware-Service``,
``NGSILD-Tenant``), the topic's ``${service}``, both (then they must agree,
or the message is refused as a request naming two tenants is), else
``--mqtt-default-tenant``; with none of them the message is rejected. The
service path: the topic's, a ``Fiware-ServicePath`` header (which must
agree with the topic's), else ``/``.

**Which tenants a topic may write** (``TSDB_MQTT_TENANTS``, ``topics``):
checked on the parsed samples, as the HTTP routes check a credential's
tenants on the parsed request; a message for another tenant is rejected
(``Forbidden``, kept in the rejected store under the tenant it named).
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from datetime import datetime

import orjson

from tsdb_service.core.credentials import redact_headers
from tsdb_service.core.errors import BadRequest, Forbidden, ParseError, PayloadTooLarge, TsdbError
from tsdb_service.core.model import EntitySample, RejectedNotification
from tsdb_service.core.timepaths import parse_time_paths
from tsdb_service.ingest.mqtt.config import MqttConfig
from tsdb_service.ingest.mqtt.topics import route, topic_tenants
from tsdb_service.parse import load_document, parse_document
from tsdb_service.parse.request_context import TenantProblem, raw_tenant, select_tenant, selectors

_ENVELOPE_KEYS = frozenset({"metadata", "body"})
_MAX_HEADERS = 100
_MAX_HEADER_BYTES = 8 * 1024


@dataclass(frozen=True, slots=True)
class Message:
    """A message as the broker delivered it to us."""

    topic: str
    payload: bytes
    qos: int
    dup: bool  # the broker has sent it to us before
    packet_id: int
    digest: bytes  # BLAKE2b-128 of topic, NUL, payload (``delivery_digest``)
    properties: tuple[tuple[str, str], ...]  # MQTT 5 user properties (and Content-Type)
    received_at: datetime


class Headers(Mapping[str, str]):
    """Header pairs as the parser reads them: ``items()`` keeps repeated
    names (two tenant headers that disagree are a refusal), a look-up
    gives the last."""

    def __init__(self, pairs: list[tuple[str, str]]):
        self._pairs = pairs
        self._last = {name: value for name, value in pairs}

    def __getitem__(self, name: str) -> str:
        return self._last[name]

    def __iter__(self) -> Iterator[str]:
        return iter(self._last)

    def __len__(self) -> int:
        return len(self._last)

    def items(self):
        return list(self._pairs)


def own_headers(message: Message, doc: dict | None) -> list[tuple[str, str]]:
    """The headers the message itself carries: its user properties, then an
    envelope's ``metadata``."""
    pairs = list(message.properties)
    if doc is not None and is_envelope(doc):
        pairs += _metadata(doc["metadata"])
    return pairs


def is_envelope(doc: dict) -> bool:
    """Orion-LD's ``{"metadata", "body"}``: both members, metadata an object,
    and nothing a notification has (a bare NGSIv2 entity needs an ``id``)."""
    return doc.keys() >= _ENVELOPE_KEYS and type(doc["metadata"]) is dict and "id" not in doc and "data" not in doc


def _metadata(metadata: dict) -> list[tuple[str, str]]:
    if len(metadata) > _MAX_HEADERS:
        raise ParseError(f"envelope 'metadata' has {len(metadata)} members; at most {_MAX_HEADERS} headers")
    pairs = []
    for name, value in metadata.items():
        if type(value) in (int, float) and type(value) is not bool:
            value = str(value)
        if type(value) is not str or len(name) + len(value) > _MAX_HEADER_BYTES:
            raise ParseError(f"envelope 'metadata' member {name[:60]!r} must be a string (an HTTP header value)")
        pairs.append((name, value))
    return pairs


def parse_message(message: Message, config: MqttConfig, values_layout=None) -> list[EntitySample]:
    """Every entity the message notifies, ready to store; a ``TsdbError``
    (4xx: the message is to be rejected) otherwise. Pure: safe to run twice."""
    if len(message.payload) > config.max_payload_bytes:
        raise PayloadTooLarge(
            f"message of {len(message.payload)} bytes exceeds the {config.max_payload_bytes}-byte limit "
            "(TSDB_MAX_BODY_BYTES); it is kept in GET /v2/notify/rejected?allTenants=true"
        )
    doc = load_document(message.payload)
    pairs = own_headers(message, doc)
    if is_envelope(doc):
        doc = doc["body"]
        if type(doc) is not dict:
            raise ParseError("envelope 'body' must be a notification object")
    headers = routed_headers(message.topic, pairs, config)
    entities = parse_document(
        doc,
        Headers(headers),
        received_at=message.received_at,
        values_layout=values_layout,
        time_paths=parse_time_paths(config.time_index_paths),
    )
    if config.tenant_rules:
        check_tenants(message.topic, {e.tenant for e in entities}, config)
    return entities


def check_tenants(topic: str, tenants: set[str], config: MqttConfig) -> None:
    """``Forbidden`` unless ``TSDB_MQTT_TENANTS`` lets ``topic`` write every one of ``tenants``."""
    allowed = topic_tenants(config.tenant_rules, topic)
    refused = sorted(tenants - allowed)
    if refused:
        names = ", ".join(repr(t) if t else "the default tenant" for t in refused)
        may = ", ".join(sorted(repr(t) if t else "'-'" for t in allowed)) or "no tenant"
        raise Forbidden(
            f"the topic {topic[:200]!r} may not write {names} (TSDB_MQTT_TENANTS lets it write {may}); "
            "nothing was stored"
        )


def routed_headers(topic: str, pairs: list[tuple[str, str]], config: MqttConfig) -> list[tuple[str, str]]:
    """``pairs`` and what the topic says (tenant, service path), or the
    default tenant; ``BadRequest`` when the message names no tenant at all
    or its topic and headers disagree on the service path."""
    found = route(config.templates, topic)
    out = list(pairs)
    if found is not None and found.service:
        out.append(("Fiware-Service", found.service))
    if found is not None and found.service_path is not None:
        given = [v.strip() for k, v in pairs if k.lower() == "fiware-servicepath" and v.strip()]
        if any(v != found.service_path for v in given):
            raise BadRequest(
                f"the topic {topic[:200]!r} names service path {found.service_path!r} and the message "
                f"{given[0][:80]!r}: name one",
                error="ParseError",
            )
        out.append(("Fiware-ServicePath", found.service_path))
    if found is None and not selectors(pairs):
        if config.default_tenant is None:
            templates = ", ".join(t.text for t in config.templates) or "(none)"
            raise BadRequest(
                f"no tenant: the topic {topic[:200]!r} matches no TSDB_MQTT_TOPIC_TEMPLATE ({templates}) and the "
                "message names none (Fiware-Service or NGSILD-Tenant in its metadata or user properties); "
                "publish to a topic a template matches, or set TSDB_MQTT_DEFAULT_TENANT ('-': the default tenant)",
                error="UnknownTenant",
            )
        if config.default_tenant:
            out.append(("Fiware-Service", config.default_tenant))
    return out


def rejected(message: Message, exc: TsdbError, config: MqttConfig) -> RejectedNotification:
    """What an operator needs to recover a refused message: its topic, the
    headers it carried (credentials redacted), its payload (the first
    ``TSDB_REJECTED_BODY_MAX_BYTES``) and size, filed under its tenant."""
    try:
        doc = load_document(message.payload) if len(message.payload) <= config.max_payload_bytes else None
    except ParseError:
        doc = None
    try:
        pairs = own_headers(message, doc)
    except ParseError:
        pairs = list(message.properties)
    size = len(message.payload)
    kept = message.payload[: config.rejected_body_max_bytes]
    return RejectedNotification(
        tenant=_tenant(message.topic, pairs, config),
        received_at=message.received_at,
        error=exc.error,
        description=exc.description,
        headers=orjson.dumps(redact_headers(dict(pairs), config.api_key_header)).decode(),
        body=kept,
        body_size=size,
        body_truncated=len(kept) < size,
        topic=message.topic,
    )


def _tenant(topic: str, pairs: list[tuple[str, str]], config: MqttConfig) -> str:
    """The tenant the rejected row is filed under: as the message names it
    (as received when the API refuses it), else the default tenant."""
    found = route(config.templates, topic)
    chosen = selectors(pairs)
    if found is not None and found.service:
        chosen.append(("fiware-service", found.service))
    if not chosen:
        return "" if found is not None else config.default_tenant or ""
    try:
        return select_tenant(chosen)
    except TenantProblem:
        return raw_tenant(chosen)
