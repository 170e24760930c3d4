"""One poison message never blocks the ones behind it (issue 37, finding 2).

A NUL character in a Text value (or in a tenant header) cannot be written to
PostgreSQL: over MQTT the message was retried forever at the head of the
queue, and nothing behind it was ever acknowledged; over HTTP it got a 503
and was lost (Orion does not retry); on DuckDB it was stored, so that store
could not be copied to PostgreSQL. Now, on both backends and transports:

* a NUL anywhere in a notification is refused when it is parsed (400 over
  HTTP), kept in the rejected store, and the next message goes on;
* anything else the database refuses for its content, again and again (a
  value it cannot hold: here a CHECK constraint of the real database
  refuses one Text value), is set aside the same way after a bounded number
  of attempts: HTTP answers 422 ``NotStorable`` (never 503), MQTT keeps it
  in the rejected store and acknowledges it; ``/health`` warns and
  ``/metrics`` counts it.
"""

from __future__ import annotations

import time
from datetime import UTC, datetime

import orjson
import psycopg
import pytest

from tests.support.mosquitto import Publisher, mqtt_settings, unique_client_id
from tsdb_service.core.model import RejectedNotification
from tsdb_service.write.ops import RecordRejected

JSON = {"Content-Type": "application/json"}
NUL = "\u0000"


def v2(entity_id: str, text: str, tenant_note: str = "") -> bytes:
    entity = {"id": entity_id, "type": "Door", "state": {"type": "Text", "value": text}}
    return orjson.dumps({"subscriptionId": "p", "data": [entity]})


def texts(client, entity_id: str, tenant: str = "poison") -> list:
    response = client.get(f"/v2/entities/{entity_id}/attrs/state", headers={"Fiware-Service": tenant})
    return response.json()["values"] if response.status_code == 200 and response.json() else []


def rejected(client) -> list[dict]:
    return client.get("/v2/notify/rejected", params={"allTenants": "true"}).json()


NUL_PLACES = {
    "a Text value": {"id": "D:1", "type": "Door", "state": {"type": "Text", "value": f"op{NUL}en"}},
    "metadata": {
        "id": "D:1",
        "type": "Door",
        "state": {"type": "Text", "value": "o", "metadata": {"m": {"value": NUL}}},
    },
    "a structured value": {"id": "D:1", "type": "Door", "state": {"type": "StructuredValue", "value": {"a": [NUL]}}},
    "an attribute type": {"id": "D:1", "type": "Door", "state": {"type": f"T{NUL}", "value": "o"}},
    "a member name": {"id": "D:1", "type": "Door", "state": {"type": "StructuredValue", "value": {NUL: 1}}},
}


@pytest.mark.parametrize("place", NUL_PLACES)
def test_a_nul_over_http_is_refused_kept_and_the_next_goes_on(client_factory, store_url, place):
    with client_factory(store_url) as client:
        body = orjson.dumps({"subscriptionId": "p", "data": [NUL_PLACES[place]]})
        response = client.post("/v2/notify", content=body, headers={**JSON, "Fiware-Service": "poison"})
        assert response.status_code == 400, response.text
        assert "NUL" in response.json()["description"]
        kept = rejected(client)
        assert len(kept) == 1 and kept[0]["tenant"] == "poison" and kept[0]["body"] == body.decode()
        ok = client.post("/v2/notify", content=v2("D:2", "closed"), headers={**JSON, "Fiware-Service": "poison"})
        assert ok.status_code == 200
        assert texts(client, "D:2") == ["closed"]
        assert texts(client, "D:1") == []


def test_a_nul_in_an_ngsi_ld_notification_is_refused(client_factory, store_url):
    with client_factory(store_url) as client:
        entity = {"id": "urn:ngsi-ld:Door:1", "type": "Door", "state": {"type": "Property", "value": f"a{NUL}"}}
        body = {"id": "urn:ngsi-ld:Notification:1", "type": "Notification", "data": [entity]}
        headers = {"Content-Type": "application/json", "NGSILD-Tenant": "poison"}
        response = client.post("/ngsi-ld/v1/notify", content=orjson.dumps(body), headers=headers)
        assert response.status_code == 400 and "NUL" in response.text
        assert len(rejected(client)) == 1


@pytest.fixture
def mqtt(client_factory, store_url, mosquitto):
    """An app consuming ``PREFIX/#`` (tenant and service path in the topic)."""
    prefix = unique_client_id("poison")
    settings = mqtt_settings(mosquitto.url, prefix)

    def start():
        return client_factory(store_url, **settings)

    with start() as client, Publisher(mosquitto.url) as publisher:
        assert client.app.state.mqtt.subscribed.wait(10)
        yield prefix, client, publisher, start


def settle(consumer, count: int, timeout: float = 30.0) -> None:
    """Until ``count`` messages are settled and every acknowledgement went out."""
    deadline = time.monotonic() + timeout
    s = consumer.stats
    while s.stored + s.rejected + s.poisoned < count or consumer._order:
        assert time.monotonic() < deadline, s
        time.sleep(0.02)


def good_behind(publisher, topic: str, name: str) -> None:
    """Three good messages behind a bad one: entities NAME:1 to NAME:3."""
    for n in range(1, 4):
        publisher.publish(topic, v2(f"{name}:{n}", f"good {n}"))


def assert_good(client, name: str) -> None:
    for n in range(1, 4):
        assert texts(client, f"{name}:{n}") == [f"good {n}"]


def test_a_nul_over_mqtt_is_set_aside_and_never_blocks(mqtt):
    prefix, client, publisher, _ = mqtt
    consumer = client.app.state.mqtt
    publisher.publish(f"{prefix}/poison", v2("M:0", f"a{NUL}b"))
    # A tenant header holding a NUL, in an envelope's metadata (Mosquitto
    # itself refuses a NUL in an MQTT 5 user property, as MQTT says).
    envelope = {"metadata": {"Fiware-Service": f"po{NUL}ison"}, "body": orjson.loads(v2("M:0", "x"))}
    publisher.publish(f"{prefix}/", orjson.dumps(envelope))
    good_behind(publisher, f"{prefix}/poison", "M")
    settle(consumer, 5)
    client.app.state.store.sync()
    assert (consumer.stats.stored, consumer.stats.rejected) == (3, 2)
    assert_good(client, "M")
    kept = {r["topic"]: r for r in rejected(client)}
    assert "NUL" in kept[f"{prefix}/poison"]["description"]
    assert orjson.loads(kept[f"{prefix}/"]["body"]) == envelope


def test_the_rejected_store_takes_a_nul_anywhere(client_factory, store_url):
    """The rejected store must take whatever is set aside: text columns
    (a tenant header as received, a description, the headers, the topic)
    with a NUL or a lone surrogate are kept with those written out."""
    with client_factory(store_url) as client:
        odd = RejectedNotification(
            tenant=f"po{NUL}ison",
            received_at=datetime.now(UTC),
            error="ParseError",
            description=f"quoting {NUL} and \ud800",
            headers=f'{{"x": "{NUL}"}}',
            body=b"raw \x00 bytes",
            topic=f"t{NUL}",
        )
        client.app.state.store.write_sync([RecordRejected(odd)])
        [row] = rejected(client)
        assert (row["tenant"], row["topic"]) == ("po\\u0000ison", "t\\u0000")
        assert row["description"] == "quoting \\u0000 and \\ud800"


@pytest.fixture
def refusing(backend, store_url):
    """The real database refuses one Text value, as it would any value it
    cannot hold: a CHECK constraint (PostgreSQL only)."""
    if backend != "postgresql":
        pytest.skip("a CHECK constraint added to a live table: PostgreSQL")

    def install() -> None:
        with psycopg.connect(store_url, autocommit=True) as conn:
            conn.execute("ALTER TABLE samples ADD CONSTRAINT poison CHECK (txt IS DISTINCT FROM 'poison')")

    return install


def metric(client, line_start: str) -> float:
    text = client.get("/metrics").text
    return float(next(line for line in text.splitlines() if line.startswith(line_start)).split()[-1])


def test_a_write_the_database_refuses_over_http_is_422_and_kept(client_factory, store_url, refusing):
    with client_factory(store_url) as client:
        refusing()
        headers = {**JSON, "Fiware-Service": "poison"}
        assert client.get("/health").json() == {"status": "pass"}
        response = client.post("/v2/notify", content=v2("H:1", "poison"), headers=headers)
        assert response.status_code == 422, response.text
        assert response.json()["error"] == "NotStorable"
        assert "poison" in response.json()["description"]  # the constraint the database named
        kept = rejected(client)
        assert [r["error"] for r in kept] == ["NotStorable"] and kept[0]["body"] == v2("H:1", "poison").decode()
        assert client.post("/v2/notify", content=v2("H:2", "fine"), headers=headers).status_code == 200
        assert texts(client, "H:2") == ["fine"]
        health = client.get("/health")
        assert health.status_code == 200 and health.json()["status"] == "warn"
        assert "refused by the database" in health.json()["output"]
        assert metric(client, "tsdb_writes_poisoned_total") == 1


def test_a_write_the_database_refuses_over_mqtt_is_set_aside_and_acknowledged(mqtt, refusing):
    prefix, client, publisher, start = mqtt
    consumer = client.app.state.mqtt
    refusing()
    publisher.publish(f"{prefix}/poison", v2("Q:0", "poison"))
    good_behind(publisher, f"{prefix}/poison", "Q")
    settle(consumer, 4)
    client.app.state.store.sync()
    assert (consumer.stats.stored, consumer.stats.poisoned) == (3, 1)
    assert_good(client, "Q")
    kept = rejected(client)
    assert [(r["error"], r["topic"]) for r in kept] == [("NotStorable", f"{prefix}/poison")]
    assert client.get("/health").json()["status"] == "warn"
    assert metric(client, 'tsdb_mqtt_messages_total{outcome="poisoned"}') == 1
    client.__exit__(None, None, None)
    with start() as again:  # acknowledged: the broker sends nothing again after a restart
        assert again.app.state.mqtt.subscribed.wait(10)
        time.sleep(0.5)
        assert again.app.state.mqtt.stats.received == 0
