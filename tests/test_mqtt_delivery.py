"""MQTT delivery (issue 31): acknowledged once stored, a redelivery stored
once, and the service working on while the broker is away.

The redelivery is made on purpose, against the real broker: the consumer's
acknowledgements are held back (as if the service had died between storing a
message and its PUBACK), then its connection is dropped; the broker sends the
unacknowledged messages again, flagged DUP, on the same session.
"""

from __future__ import annotations

import time

import orjson
import pytest

from tests.support.mosquitto import Publisher, unique_client_id
from tests.support.mqtt_service import Feed, consuming, rejected_on, timed, v2
from tsdb_service.demo.mosquitto import LocalMosquitto, free_port


def wait_for(condition, timeout: float = 20.0, what: str = "the condition") -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(0.02)


@pytest.fixture
def feed(client_factory, store_url, mosquitto):
    prefix, client = consuming(client_factory, store_url, mosquitto)
    with client, Publisher(mosquitto.url) as publisher:
        yield Feed(client, client.app, publisher, prefix)


def drop_connection_with_acks_held(feed, monkeypatch) -> None:
    """Hold every acknowledgement back, then break the connection (no
    DISCONNECT): what the broker sees of a service that died after storing."""
    monkeypatch.setattr(type(feed.consumer), "_ack", lambda self, item: None)


def test_a_redelivery_of_stored_messages_is_acknowledged_not_stored_again(feed, monkeypatch):
    consumer = feed.consumer
    drop_connection_with_acks_held(feed, monkeypatch)
    for n in range(5):
        feed.publish("v2/acme/", v2({"id": f"R:{n}", "type": "Robot", "n": timed(n)}))
    feed.publish("v2/acme/", b"[broken")
    feed.settled(6)
    assert (consumer.stats.stored, consumer.stats.rejected) == (5, 1)
    monkeypatch.undo()  # acknowledge again from now on
    connects = consumer.stats.connects
    consumer._client._sock_close()  # the connection breaks; paho reconnects, the session resumes
    wait_for(lambda: consumer.stats.redelivered == 6, what="the six redeliveries")
    assert consumer.stats.connects == connects + 1
    assert (consumer.stats.stored, consumer.stats.rejected) == (5, 1)
    feed.app.state.store.sync()
    for n in range(5):
        _, entity = feed.history(f"R:{n}", "acme")
        assert entity["attributes"] == [{"attrName": "n", "values": [n]}]  # once
    assert rejected_on(feed, "v2/acme/")["body"] == "[broken"  # kept once
    wait_for(lambda: not consumer._order, what="the acknowledgements")
    consumer._client._sock_close()  # acknowledged now: nothing comes back
    wait_for(lambda: consumer.subscribed.is_set() and consumer.stats.connects == connects + 2, what="a reconnection")
    feed.publish("v2/acme/", v2({"id": "R:after", "type": "Robot", "n": timed(9)}))  # behind anything resent
    feed.settled(13)
    assert (consumer.stats.redelivered, consumer.stats.received) == (6, 13)


def test_an_identical_message_that_is_not_a_redelivery_is_stored(feed):
    """Two publications of the same bytes are two notifications (a value
    that went back to what it was): only a DUP redelivery is looked up."""
    body = v2({"id": "R:same", "type": "Robot", "door": {"type": "Text", "value": "open"}})
    feed.publish("v2/acme/", body)
    feed.publish("v2/acme/", body)
    feed.settled(2)
    assert feed.consumer.stats.stored == 2 and feed.consumer.stats.redelivered == 0


def test_http_goes_on_and_health_says_mqtt_is_down_until_the_broker_comes(client_factory, tmp_path):
    """Backend-neutral: on DuckDB only."""
    port = free_port()
    client = client_factory(
        str(tmp_path / "db.duckdb"),
        mqtt_url=f"mqtt://127.0.0.1:{port}",
        mqtt_client_id=unique_client_id("down"),
        mqtt_reconnect_max_s=1,
    )
    with client:
        health = client.get("/health")
        assert health.status_code == 200 and health.json()["status"] == "warn"
        assert (
            f"MQTT mqtt://127.0.0.1:{port}" in health.json()["output"]
            and "HTTP ingest and reads work" in health.json()["output"]
        )
        body = v2({"id": "R:http", "type": "Robot", "x": timed(1)})
        notified = client.post("/v2/notify", content=orjson.dumps(body), headers={"Content-Type": "application/json"})
        assert notified.status_code == 200
        assert client.get("/v2/entities/R:http").json()["attributes"] == [{"attrName": "x", "values": [1]}]
        metrics = client.get("/metrics").text
        assert "tsdb_mqtt_connected 0.0" in metrics
        with LocalMosquitto(port=port, directory=tmp_path / "broker"):
            wait_for(lambda: client.get("/health").json()["status"] == "pass", what="MQTT to be up")
            assert "tsdb_mqtt_connected 1.0" in client.get("/metrics").text
