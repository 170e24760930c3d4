"""Orion subscriptions that make a real broker feed us, and recorded examples.

The payloads are built here, not read from ``notifications/``, so that
``tsdb-service subscribe`` works from an installed wheel; ``notifications/``
holds the same documents written out by ``tsdb-service notifications build``
(a test keeps the two identical).
"""

from __future__ import annotations

import itertools
import random
from datetime import UTC, datetime
from pathlib import Path

import httpx
import orjson

from . import orion
from .base import Simulator
from .usecases import SIMULATORS

DEFAULT_NOTIFY_URL = "http://tsdb-service:8668/v2/notify"

_EXAMPLE_START = datetime(2025, 6, 2, 9, 0, tzinfo=UTC)


def _data(entity: dict, attr: str) -> object:
    return entity.get(attr, {}).get("value", {}).get("data")


# The recorded example of each use case: its first notification that shows
# the interesting part (an operator's cmd_vel, a door opening, a drone in flight).
_EXAMPLE_WANTED = {
    "lawnmower": lambda e: "cmd_vel" in e and _data(e, "navigationState") == 5,
    "warehouse": lambda e: _data(e, "doorCommand") == 1 and _data(e, "doorState") == 2,
    "drone": lambda e: _data(e, "missionState") == 2,
}


def subscription(sim: Simulator, notify_url: str = DEFAULT_NOTIFY_URL) -> dict:
    """The NGSIv2 subscription for one use case: every change of its entities,
    the whole entity, normalized, with the IoT Agent's TimeInstant metadata."""
    return {
        "description": f"tsdb-service: history of the {sim.title}",
        "subject": {
            "entities": [{"idPattern": pattern, "type": entity_type} for pattern, entity_type in sim.subjects],
        },
        "notification": {
            "http": {"url": notify_url},
            "attrsFormat": "normalized",
            "metadata": ["TimeInstant"],
            "onlyChangedAttrs": False,
        },
        "throttling": 0,
    }


def broker_headers(sim: Simulator) -> dict[str, str]:
    """The tenancy headers a subscription must be created under."""
    return {
        "Content-Type": "application/json",
        "Fiware-Service": sim.tenancy.service,
        "Fiware-ServicePath": sim.tenancy.service_path,
    }


def post_subscription(broker: str, sim: Simulator, notify_url: str, timeout: float = 10.0) -> tuple[bool, str]:
    """Create the subscription on a broker; (created?, what the broker answered)."""
    url = broker.rstrip("/") + "/v2/subscriptions"
    body = orjson.dumps(subscription(sim, notify_url))
    try:
        response = httpx.post(url, content=body, headers=broker_headers(sim), timeout=timeout)
    except httpx.HTTPError as exc:
        return False, f"could not reach {url}: {type(exc).__name__}: {exc}"
    location = response.headers.get("location", "")
    if response.status_code == 201:
        sub_id = location.rsplit("/", 1)[-1] or "?"
        return True, f"201 Created: subscription {sub_id} ({location}) on tenant {sim.tenancy.service!r}"
    return False, f"{response.status_code} {response.reason_phrase}: {response.text.strip()[:500]}"


def example_notification(sim: Simulator) -> tuple[dict[str, str], dict]:
    """A notification from a fixed-seed run, with the headers a broker at
    ``tsdb-service:8668`` would send along (including those libcurl adds)."""
    wire = random.Random(f"example:{sim.name}:orion")
    emissions = sim.emissions(_EXAMPLE_START, random.Random(f"example:{sim.name}"))
    wanted = _EXAMPLE_WANTED[sim.name]
    chosen = next(e for e in itertools.islice(emissions, 100_000) if wanted(e.entity))
    body_bytes = orion.notification_body(orion.subscription_id(wire), chosen.entity)
    headers = {"Host": "tsdb-service:8668"}
    headers.update(orion.notification_headers(sim.tenancy.service, sim.tenancy.service_path, orion.correlator(wire)))
    headers["Content-Length"] = str(len(body_bytes))
    return headers, orjson.loads(body_bytes)


def write_examples(root: Path) -> list[Path]:
    """Write ``notifications/<use case>/`` for every use case; returns the files written."""
    written = []
    for name, sim in SIMULATORS.items():
        folder = root / name
        folder.mkdir(parents=True, exist_ok=True)
        headers, body = example_notification(sim)
        documents = {
            "subscription.json": subscription(sim),
            "subscription.headers.json": broker_headers(sim),
            "notification.json": body,
            "notification.headers.json": headers,
        }
        for filename, document in documents.items():
            path = folder / filename
            path.write_bytes(dumps(document))
            written.append(path)
    return written


def dumps(document: object) -> bytes:
    """Pretty, stable JSON with a final newline, for files people read and diff."""
    return orjson.dumps(document, option=orjson.OPT_INDENT_2) + b"\n"
