"""Notifications exactly as Orion sends them, for entities an IoT Agent updates.

What a real deployment delivers, and therefore what the simulators send:

* The IoT Agent updates some attributes of an entity, adds a ``TimeInstant``
  attribute (the measurement time) and a ``TimeInstant`` metadata on each
  attribute it touched; attributes it did not touch keep their old metadata.
* Orion then notifies the *whole* entity (``onlyChangedAttrs`` is false by
  default) in the ``normalized`` format, one entity per notification, with
  its own headers: tenant, service path, a correlator with ``cbnotif``, the
  attrs format, a JSON content type with charset, and its user agent.
"""

from __future__ import annotations

import random
import uuid
from dataclasses import dataclass, field
from datetime import UTC, datetime
from typing import Any

import orjson

ORION_USER_AGENT = "orion/4.1.0 libcurl/7.88.1"
CONTENT_TYPE = "application/json; charset=utf-8"


def iso(at: datetime) -> str:
    """ISO-8601 UTC with milliseconds and a ``Z``: the way IoT Agents write TimeInstant."""
    return at.astimezone(UTC).strftime("%Y-%m-%dT%H:%M:%S.") + f"{at.microsecond // 1000:03d}Z"


@dataclass
class EntityState:
    """An entity as the broker holds it: each attribute remembers when it was last set."""

    id: str
    type: str
    attrs: dict[str, tuple[str, Any, datetime]] = field(default_factory=dict)

    def set(self, name: str, ngsi_type: str, value: Any, at: datetime) -> None:
        self.attrs[name] = (ngsi_type, value, at)

    def value(self, name: str) -> Any:
        return self.attrs[name][1]

    def snapshot(self, at: datetime) -> dict:
        """The entity in NGSIv2 normalized form, as notified after an update at ``at``."""
        stamp = iso(at)
        entity: dict[str, Any] = {"id": self.id, "type": self.type}
        entity["TimeInstant"] = {"type": "DateTime", "value": stamp, "metadata": {}}
        for name, (ngsi_type, value, updated) in self.attrs.items():
            entity[name] = {
                "type": ngsi_type,
                "value": value,
                "metadata": {"TimeInstant": {"type": "DateTime", "value": iso(updated)}},
            }
        return entity


def subscription_id(rng: random.Random) -> str:
    """A 24-hex-digit id, the shape of the ObjectIds Orion gives subscriptions."""
    return f"{rng.getrandbits(96):024x}"


def correlator(rng: random.Random, notification_number: int = 1) -> str:
    """Orion's ``Fiware-Correlator`` on a notification: the triggering request's
    id followed by ``; cbnotif=N``."""
    return f"{uuid.UUID(int=rng.getrandbits(128), version=4)}; cbnotif={notification_number}"


def notification_body(subscription: str, entity: dict) -> bytes:
    """The compact JSON body Orion posts: one entity under ``data``."""
    return orjson.dumps({"subscriptionId": subscription, "data": [entity]})


def notification_headers(service: str, service_path: str, corr: str) -> dict[str, str]:
    """The headers Orion adds to an NGSIv2 ``normalized`` notification.

    ``Host`` and ``Content-Length`` are left to the HTTP client, as libcurl does.
    """
    return {
        "User-Agent": ORION_USER_AGENT,
        "Fiware-Service": service.lower(),
        "Fiware-ServicePath": service_path,
        "Accept": "application/json",
        "Content-Type": CONTENT_TYPE,
        "Fiware-Correlator": corr,
        "Ngsiv2-AttrsFormat": "normalized",
    }
