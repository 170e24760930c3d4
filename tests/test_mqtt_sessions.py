"""MQTT sessions (issue 37, finding 10): a lost session is a fresh duplicate window; a guessable id is warned.

Packet ids belong to a broker session. After the broker lost ours (here:
restarted without its saved state), it numbers our messages from 1 again,
and a new message that reuses a packet id with the same bytes as one stored
before the loss is not a redelivery of it. Such a message, received but not
stored when the service is killed, comes again flagged DUP on the new
session: it must be stored then, not taken for the old one and dropped.
With real processes: the broker, and the service SIGSTOPped while the
message reaches it, then SIGKILLed and restarted.
"""

from __future__ import annotations

import logging
import os
import signal
import time

import httpx
import orjson

from tests.support.mosquitto import Publisher, broker, mqtt_args, ready, unique_client_id
from tests.support.server import ServerProcess

TENANT = "sessions"
# No time in the body: each notification is stored at its reception time,
# so two publications of these same bytes are two samples.
BODY = orjson.dumps({"subscriptionId": "s", "data": [{"id": "Door:1", "type": "Door", "state": "open"}]})


def samples(server: ServerProcess) -> int:
    response = httpx.get(server.url + "/v2/entities/Door:1", headers={"Fiware-Service": TENANT}, timeout=10)
    if response.status_code == 404:
        return 0
    return len(response.json()["index"])


def wait_samples(server: ServerProcess, count: int, timeout: float = 20.0) -> int:
    deadline = time.monotonic() + timeout
    while (got := samples(server)) < count and time.monotonic() < deadline:
        time.sleep(0.1)
    return got


def health(server: ServerProcess) -> str:
    return httpx.get(server.url + "/health", timeout=5).json()["status"]


def reconnected_fresh(server: ServerProcess, connections_before: int) -> bool:
    """A connection newer than the first ``connections_before`` started a new session."""
    parts = server.output().split("connected to")
    return len(parts) - 1 > connections_before and "started a new session" in parts[-1]


def lose_session(mosquitto) -> None:
    """Restart the broker without what it saved: every session is gone."""
    mosquitto.stop()
    for saved in mosquitto.directory.glob("*.db"):
        saved.unlink()
    mosquitto.start()


def test_a_message_after_a_lost_session_is_not_taken_for_a_redelivery(store_url, tmp_path):
    mosquitto = broker(tmp_path / "broker")
    prefix = unique_client_id("sessions")
    server = ServerProcess(store_url, args=mqtt_args(mosquitto.url, prefix, unique_client_id("svc")), log_dir=tmp_path)
    topic = f"{prefix}/{TENANT}/"
    try:
        ready(server.start())
        with Publisher(mosquitto.url) as publisher:
            publisher.publish(topic, BODY)  # packet id 1 of our first session
        assert wait_samples(server, 1) == 1

        # Wait for a connection after the loss, not the first one: the
        # service may not have seen the broker go yet.
        connections = server.output().count("connected to")
        lose_session(mosquitto)
        deadline = time.monotonic() + 30
        while not reconnected_fresh(server, connections) or health(server) != "pass":
            assert time.monotonic() < deadline, server.output()[-3000:]
            time.sleep(0.1)
        ready(server)

        # The same bytes again: packet id 1 of the new session. It reaches
        # the stopped service, which is then killed before storing it.
        os.kill(server.pid, signal.SIGSTOP)
        try:
            with Publisher(mosquitto.url) as publisher:
                publisher.publish(topic, BODY)
            time.sleep(0.5)  # the broker sends it into the stopped service's socket
        finally:
            server.kill()
        ready(server.start())  # the session resumes: the broker sends it again, flagged DUP
        assert wait_samples(server, 2) == 2, server.output()[-3000:]
        time.sleep(0.3)
        assert samples(server) == 2
    finally:
        if server.running():
            server.terminate()
        mosquitto.close()


def test_the_default_client_id_on_a_broker_without_authentication_is_warned(
    client_factory, store_url, mosquitto, caplog
):
    """The broker took us anonymously under ``tsdb-service-HOSTNAME``:
    anyone can take our session. Said once at start; not with an id of our own."""
    caplog.set_level(logging.WARNING, logger="tsdb_service.ingest.mqtt.consumer")
    topics = f"{unique_client_id('guess')}/#"
    with client_factory(store_url, mqtt_url=mosquitto.url, mqtt_topics=topics) as client:
        assert client.app.state.mqtt.subscribed.wait(10)
    warned = [r.getMessage() for r in caplog.records if "anyone can guess" in r.getMessage()]
    assert len(warned) == 1 and "TSDB_MQTT_CLIENT_ID" in warned[0] and "tsdb-service-" in warned[0]
    caplog.clear()
    with client_factory(store_url, mqtt_url=mosquitto.url, mqtt_topics=topics, mqtt_client_id=unique_client_id("own")):
        pass
    assert not [r for r in caplog.records if "anyone can guess" in r.getMessage()]
