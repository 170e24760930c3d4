"""Entity updates for a real broker: what an IoT Agent sends Orion or Orion-LD.

``tsdb-service demo --broker URL`` feeds the simulators' entities to a broker
instead of notifying this service directly; the broker then notifies us
through the subscriptions ``tsdb-service subscribe`` made, so the whole
path a deployment uses (update, subscription, notification) is exercised.

* NGSIv2 (Orion): ``POST /v2/op/update`` with ``actionType: append`` (create
  or update), the entity in normalized form with its ``TimeInstant``
  attribute and metadata, under the use case's ``Fiware-Service`` and
  ``Fiware-ServicePath``.
* NGSI-LD (Orion-LD): ``POST /ngsi-ld/v1/entityOperations/upsert?options=update``
  with the entity as NGSI-LD Properties (a ``geo:json`` attribute is a
  GeoProperty), each attribute's ``TimeInstant`` as its ``observedAt``,
  under ``NGSILD-Tenant``; no ``@context`` (the core one), so the names stay
  the short terms the subscription is notified with.
"""

from __future__ import annotations

from typing import Any

import orjson

from tsdb_service.broker.subscriptions import broker_headers, ld_broker_headers
from tsdb_service.usecases.base import Simulator

V2_UPDATE = "/v2/op/update"
LD_UPSERT = "/ngsi-ld/v1/entityOperations/upsert?options=update"


def update_request(sim: Simulator, entity: dict, ngsi_ld: bool = False) -> tuple[str, dict[str, str], bytes]:
    """``(path, headers, body)`` of the request that sets ``entity`` (NGSIv2
    normalized, as the simulators emit it) on the broker."""
    if ngsi_ld:
        return LD_UPSERT, ld_broker_headers(sim), orjson.dumps([ld_entity(entity)])
    return V2_UPDATE, broker_headers(sim), orjson.dumps({"actionType": "append", "entities": [entity]})


def ld_entity(entity: dict) -> dict[str, Any]:
    """An NGSIv2 normalized entity as NGSI-LD: ``TimeInstant`` metadata become
    ``observedAt``, ``geo:json`` a GeoProperty, everything else a Property
    with the same value (ROS messages stay JSON objects)."""
    out: dict[str, Any] = {"id": entity["id"], "type": entity["type"]}
    for name, attr in entity.items():
        if name in ("id", "type", "TimeInstant") or not isinstance(attr, dict):
            continue
        kind = "GeoProperty" if attr.get("type") == "geo:json" else "Property"
        prop: dict[str, Any] = {"type": kind, "value": attr.get("value")}
        observed = (attr.get("metadata") or {}).get("TimeInstant", {}).get("value")
        if observed is not None:
            prop["observedAt"] = observed
        out[name] = prop
    return out
