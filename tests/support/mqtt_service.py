"""The service consuming MQTT, as the MQTT tests drive it.

``Feed`` is one in-process app consuming ``PREFIX/#`` of a private Mosquitto
(``consuming`` makes its settings), with a publisher and the history API to
read back; ``stored_notifications`` and ``settled`` count what a use case's
entities hold. ``timed`` and ``v2`` build NGSIv2 notifications.
"""

from __future__ import annotations

import time
from urllib.parse import quote

import httpx
import orjson

from tests.support.mosquitto import Publisher, unique_client_id
from tests.support.server import ServerProcess

T = "2025-02-03T04:05:06.789Z"


def timed(value, kind: str = "Number") -> dict:
    return {"type": kind, "value": value, "metadata": {"TimeInstant": {"type": "DateTime", "value": T}}}


def v2(entity: dict) -> dict:
    return {"subscriptionId": "57458eb60962ef754e7c0998", "data": [entity]}


class Feed:
    """One app consuming ``prefix/#`` of the session's broker."""

    def __init__(self, client, app, publisher: Publisher, prefix: str):
        self.client, self.app, self.publisher, self.prefix = client, app, publisher, prefix
        self.published = 0  # by this feed: what the consumer is to settle in all
        assert self.consumer.subscribed.wait(10), "the consumer never subscribed"

    @property
    def consumer(self):
        return self.app.state.mqtt

    def publish(self, topic: str, payload, **kw) -> None:
        data = payload if isinstance(payload, bytes) else orjson.dumps(payload)
        self.publisher.publish(f"{self.prefix}/{topic}", data, **kw)
        self.published += 1

    def settled(self, count: int, timeout: float = 20.0) -> None:
        """Wait until ``count`` messages were stored or rejected in all."""
        deadline = time.monotonic() + timeout
        stats = self.consumer.stats
        while stats.stored + stats.rejected + stats.redelivered < count:
            assert time.monotonic() < deadline, f"only {stats} of {count} messages settled"
            time.sleep(0.02)
        self.app.state.store.sync()

    def history(self, entity_id: str, tenant: str, path: str | None = None):
        headers = {"Fiware-Service": tenant, **({"Fiware-ServicePath": path} if path else {})}
        response = self.client.get(f"/v2/entities/{quote(entity_id, safe='')}", headers=headers)
        return response.status_code, response.json()


def consuming(client_factory, store_url, mosquitto, **settings):
    prefix = unique_client_id("topic")
    options = {
        "mqtt_url": mosquitto.url,
        "mqtt_client_id": unique_client_id("svc"),
        "mqtt_topics": f"{prefix}/#",
        "mqtt_topic_template": f"{prefix}/v2/${{service}}${{servicePath}}",
        **settings,
    }
    return prefix, client_factory(store_url, **options)


def rejected_on(feed, topic: str) -> dict:
    rows = feed.client.get("/v2/notify/rejected", params={"allTenants": "true", "limit": 1000}).json()
    found = [row for row in rows if row["topic"] == f"{feed.prefix}/{topic}"]
    assert len(found) == 1, rows
    return found[0]


def stored_notifications(service: ServerProcess, sim) -> int:
    """Rows (one per notified entity) the service holds for the use case."""
    headers = {"Fiware-Service": sim.tenancy.service, "Fiware-ServicePath": sim.tenancy.service_path}
    total = 0
    for entity in httpx.get(service.url + "/v2/entities", headers=headers, timeout=10).json():
        history = httpx.get(f"{service.url}/v2/entities/{entity['id']}", params={"limit": 100_000}, headers=headers)
        total += len(history.json()["index"])
    return total


def settled(service: ServerProcess, sim, expected: int) -> int:
    deadline = time.monotonic() + 30
    while (got := stored_notifications(service, sim)) < expected and time.monotonic() < deadline:
        time.sleep(0.2)
    return got
