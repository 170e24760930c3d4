"""Where a replay sends history, in the shapes each receiver documents.

* ``OrionTarget``: NGSIv2 ``POST /v2/op/update`` with ``actionType:
  append`` (create or update), the entities in normalized form, under
  ``Fiware-Service`` and ``Fiware-ServicePath``.
* ``OrionLdTarget``: NGSI-LD ``POST /ngsi-ld/v1/entityOperations/upsert?options=update``,
  the entities as Properties (GeoProperty for geometries, Relationship
  with ``object``), each with ``observedAt``, under ``NGSILD-Tenant``;
  ``application/json`` without ``@context`` (the core context).
* ``NotifyTarget``: another tsdb-service's ``POST /v2/notify``, an Orion
  ``normalized`` notification.
* ``MqttTarget``: published at QoS 1 as Orion publishes a notification
  (the bare body; the tenant and service path in the topic, macros
  ``${service}`` and ``${servicePath}``) or as Orion-LD does (``{"metadata":
  {HEADERS}, "body": NOTIFICATION}``): exactly what the MQTT consumer of
  ``ingest.mqtt`` reads.

Every update carries the marker attribute ``tsdbReplay`` (``MARKER``):
``{"replay": ID, "source": WHERE, "originalTime": ISO}``, so nobody takes
it for live data, and a ``TimeInstant`` (NGSIv2) or ``observedAt``
(NGSI-LD) of the time it is sent as.

What it trusts: only the URL given on the command line. No redirect is
followed, no URL is taken from the data, proxy variables are not used;
a refusal (any status but 2xx) or a failed connection ends the replay
with one line.
"""

from __future__ import annotations

import os
import ssl
import uuid
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Any, Protocol
from urllib.parse import urlsplit

import orjson

from tsdb_service.commands.replay.source import Update
from tsdb_service.geo.encodings import from_ngsi

MARKER = "tsdbReplay"
TIME_INSTANT = "TimeInstant"
V2_UPDATE = "/v2/op/update"
LD_UPSERT = "/ngsi-ld/v1/entityOperations/upsert"
MQTT_TOPIC = "tsdb/${service}${servicePath}"
MQTT_PASSWORD_VARIABLE = "TSDB_MQTT_PASSWORD"
_GEO_TYPES = frozenset({"geo:json", "geo:point", "geo:line", "geo:box", "geo:polygon", "geoproperty"})
_SKIPPED = frozenset({TIME_INSTANT, MARKER})  # set anew on every replayed update


class ReplayError(RuntimeError):
    """A target refused or could not be reached; one line."""


@dataclass(frozen=True, slots=True)
class Marker:
    replay: str  # this replay's id
    source: str  # where the history came from (tenant, service path, store)

    def value(self, original: datetime) -> dict:
        return {"replay": self.replay, "source": self.source, "originalTime": iso(original)}


@dataclass(frozen=True, slots=True)
class Outgoing:
    """The updates of one instant for one tenant and service path, and the time they are sent as."""

    tenant: str
    service_path: str
    updates: Sequence[Update]
    time: datetime  # TimeInstant / observedAt: the original time, or the present with --retime


class Target(Protocol):
    name: str  # for the report: "Orion at http://..."

    def send(self, batch: Outgoing, marker: Marker) -> None: ...

    def close(self) -> None: ...


def iso(moment: datetime) -> str:
    return moment.astimezone(UTC).isoformat(timespec="microseconds").replace("+00:00", "Z")


# --- shapes ------------------------------------------------------------------------


def v2_entity(update: Update, sent_as: datetime, marker: Marker) -> dict[str, Any]:
    """NGSIv2 normalized: each attribute with its stored type and value."""
    entity: dict[str, Any] = {"id": update.entity_id, "type": update.entity_type}
    for name, ngsi_type, value in update.attrs:
        if name not in _SKIPPED:
            entity[name] = {"type": ngsi_type or "None", "value": value}
    entity[TIME_INSTANT] = {"type": "DateTime", "value": iso(sent_as)}
    entity[MARKER] = {"type": "StructuredValue", "value": marker.value(update.time)}
    return entity


def ld_entity(update: Update, sent_as: datetime, marker: Marker) -> dict[str, Any]:
    """NGSI-LD normalized: Property, GeoProperty (a geometry as GeoJSON) or
    Relationship, each observed at ``sent_as``; a null value is left out
    (in NGSI-LD it would delete the attribute)."""
    observed = iso(sent_as)
    entity: dict[str, Any] = {"id": update.entity_id, "type": update.entity_type}
    for name, ngsi_type, value in update.attrs:
        if name in _SKIPPED or value is None:
            continue
        lowered = ngsi_type.lower()
        geometry = from_ngsi(lowered, value) if lowered in _GEO_TYPES else None
        if geometry is not None:
            entity[name] = {"type": "GeoProperty", "value": orjson.loads(geometry.geojson), "observedAt": observed}
        elif lowered == "relationship":
            entity[name] = {"type": "Relationship", "object": value, "observedAt": observed}
        else:
            entity[name] = {"type": "Property", "value": value, "observedAt": observed}
    entity[MARKER] = {"type": "Property", "value": marker.value(update.time), "observedAt": observed}
    return entity


def v2_notification(batch: Outgoing, marker: Marker) -> dict[str, Any]:
    data = [v2_entity(u, batch.time, marker) for u in batch.updates]
    return {"subscriptionId": f"tsdb-replay-{marker.replay}", "data": data}


def ld_notification(batch: Outgoing, marker: Marker) -> dict[str, Any]:
    return {
        "id": f"urn:ngsi-ld:Notification:{uuid.uuid4()}",
        "type": "Notification",
        "subscriptionId": f"urn:ngsi-ld:Subscription:tsdb-replay-{marker.replay}",
        "notifiedAt": iso(datetime.now(UTC)),
        "data": [ld_entity(u, batch.time, marker) for u in batch.updates],
    }


# --- HTTP ---------------------------------------------------------------------------


class _Http:
    """One connection pool to the one URL the operator named."""

    def __init__(self, url: str, what: str):
        import httpx

        self.base = url.rstrip("/")
        self.name = f"{what} at {self.base}"
        self._client = httpx.Client(timeout=httpx.Timeout(30.0, connect=10.0), follow_redirects=False, trust_env=False)

    def post(self, path: str, body: Any, headers: dict[str, str]) -> None:
        import httpx

        try:
            answer = self._client.post(
                self.base + path, content=orjson.dumps(body), headers={"Content-Type": "application/json", **headers}
            )
        except httpx.HTTPError as exc:
            raise ReplayError(f"cannot reach {self.name}: {exc or type(exc).__name__}") from None
        if not 200 <= answer.status_code < 300:
            text = " ".join(answer.text.split())[:300]
            raise ReplayError(f"{self.name} refused the replayed updates ({answer.status_code} {text})")

    def close(self) -> None:
        self._client.close()


class OrionTarget(_Http):
    def __init__(self, url: str):
        super().__init__(url, "Orion")

    def send(self, batch: Outgoing, marker: Marker) -> None:
        headers = {"Fiware-Service": batch.tenant, "Fiware-ServicePath": batch.service_path}
        entities = [v2_entity(u, batch.time, marker) for u in batch.updates]
        self.post(V2_UPDATE, {"actionType": "append", "entities": entities}, _without_empty(headers))


class OrionLdTarget(_Http):
    def __init__(self, url: str):
        super().__init__(url, "Orion-LD")

    def send(self, batch: Outgoing, marker: Marker) -> None:
        entities = [ld_entity(u, batch.time, marker) for u in batch.updates]
        self.post(f"{LD_UPSERT}?options=update", entities, _without_empty({"NGSILD-Tenant": batch.tenant}))


class NotifyTarget(_Http):
    def __init__(self, url: str):
        super().__init__(url, "tsdb-service")

    def send(self, batch: Outgoing, marker: Marker) -> None:
        headers = {
            "Fiware-Service": batch.tenant,
            "Fiware-ServicePath": batch.service_path,
            "Ngsiv2-AttrsFormat": "normalized",
        }
        self.post("/v2/notify", v2_notification(batch, marker), _without_empty(headers))


def _without_empty(headers: dict[str, str]) -> dict[str, str]:
    return {k: v for k, v in headers.items() if v}  # no tenant header: the default tenant


# --- MQTT ---------------------------------------------------------------------------


class MqttTarget:
    """Publishes each batch at QoS 1 and waits for the broker's acknowledgement."""

    def __init__(self, url: str, topic: str = MQTT_TOPIC, ld: bool = False, username: str = ""):
        import paho.mqtt.client as mqtt

        parts = urlsplit(url)
        self.name = f"MQTT broker {url} ({'Orion-LD' if ld else 'Orion'} shape, topic {topic})"
        self._topic, self._ld = topic, ld
        self._client = mqtt.Client(
            mqtt.CallbackAPIVersion.VERSION2, client_id=f"tsdb-replay-{uuid.uuid4().hex[:12]}", protocol=mqtt.MQTTv311
        )
        if username:
            self._client.username_pw_set(username, os.environ.get(MQTT_PASSWORD_VARIABLE) or None)
        if parts.scheme == "mqtts":
            self._client.tls_set_context(ssl.create_default_context())
        try:
            self._client.connect(
                parts.hostname or "localhost", parts.port or (8883 if parts.scheme == "mqtts" else 1883)
            )
        except OSError as exc:
            raise ReplayError(f"cannot reach the MQTT broker {url}: {exc}") from None
        self._client.loop_start()

    def topic(self, tenant: str, service_path: str) -> str:
        return self._topic.replace("${service}", tenant).replace("${servicePath}", service_path)

    def send(self, batch: Outgoing, marker: Marker) -> None:
        if self._ld:
            metadata = {
                "Content-Type": "application/json",
                "NGSILD-Tenant": batch.tenant,
                "Fiware-ServicePath": batch.service_path,
                "Ngsild-Attribute-Format": "Normalized",
            }
            payload: Any = {"metadata": _without_empty(metadata), "body": ld_notification(batch, marker)}
        else:
            payload = v2_notification(batch, marker)
        info = self._client.publish(self.topic(batch.tenant, batch.service_path), orjson.dumps(payload), qos=1)
        try:
            info.wait_for_publish(timeout=30)
        except (RuntimeError, ValueError) as exc:
            raise ReplayError(f"the {self.name} did not take a message: {exc}") from None
        if not info.is_published():
            raise ReplayError(f"the {self.name} did not acknowledge a message within 30 s")

    def close(self) -> None:
        self._client.loop_stop()
        self._client.disconnect()
