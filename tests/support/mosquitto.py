"""A real MQTT broker for the tests: Debian's ``mosquitto``, private to the run.

``broker()`` installs the package when it is missing and we may (root,
apt-get), else skips with the reason, and starts ``LocalMosquitto``
(``tsdb_service.demo.mosquitto``) on a free port of 127.0.0.1 with its own
persistence directory, as ``pg_cluster`` does for PostgreSQL.
``Publisher`` publishes the way Orion does (QoS 1, waiting for the broker's
PUBACK), and reconnects by itself when the broker is restarted.
"""

from __future__ import annotations

import itertools
import os
import threading
import time

import httpx
import paho.mqtt.client as paho
import pytest
from paho.mqtt.packettypes import PacketTypes
from paho.mqtt.properties import Properties

from tests.support.apt import apt_install
from tests.support.server import ServerProcess
from tsdb_service.demo.mosquitto import LocalMosquitto, find_mosquitto

__all__ = [
    "Publisher",
    "broker",
    "mosquitto_binary",
    "mqtt_args",
    "mqtt_outcome",
    "mqtt_settings",
    "ready",
    "unique_client_id",
]

_ids = itertools.count(1)


def mosquitto_binary() -> str:
    """The broker's binary, installed here if missing; skips the test otherwise."""
    found = find_mosquitto()
    if found is None:
        reason = apt_install("mosquitto")
        if reason is not None:
            pytest.skip(reason)
        found = find_mosquitto()
    if found is None:
        pytest.skip("apt-get installed mosquitto but no mosquitto binary was found")
    return found


def broker(tmp_dir: str | os.PathLike | None = None) -> LocalMosquitto:
    """A started private broker (the caller closes it)."""
    return LocalMosquitto(mosquitto_binary(), directory=tmp_dir).start()


def unique_client_id(name: str) -> str:
    """A client id no other test of the run uses: each names its own broker session."""
    return f"tsdb-test-{name}-{os.getpid()}-{next(_ids)}"


class Publisher:
    """One MQTT 5 client that publishes and waits for the broker's
    acknowledgement. Its session persists (clean start off, 5 minutes):
    across a broker restart paho sends again what was not acknowledged, and
    at QoS 2 the broker then knows what it already has; at QoS 1 it may keep
    a message twice (MQTT's at-least-once between publisher and broker)."""

    def __init__(self, url: str, client_id: str | None = None):
        host, port = url.removeprefix("mqtt://").rsplit(":", 1)
        self.client = paho.Client(
            paho.CallbackAPIVersion.VERSION2, client_id=client_id or unique_client_id("pub"), protocol=paho.MQTTv5
        )
        self.client.reconnect_delay_set(1, 1)
        self._connected = threading.Event()
        self._acked: set[int] = set()
        self._lock = threading.Condition()
        self.client.on_connect = lambda c, u, f, rc, p: self._connected.set() if not rc.is_failure else None
        self.client.on_disconnect = lambda c, u, f, rc, p: self._connected.clear()
        self.client.on_publish = self._on_publish
        properties = Properties(PacketTypes.CONNECT)
        properties.SessionExpiryInterval = 300
        self.client.connect_async(host, int(port), keepalive=10, clean_start=False, properties=properties)
        self.client.loop_start()
        if not self._connected.wait(10):
            raise RuntimeError(f"cannot connect to {url}")

    def _on_publish(self, client, userdata, mid, reason_code, properties) -> None:
        with self._lock:
            self._acked.add(mid)
            self._lock.notify_all()

    def publish(
        self,
        topic: str,
        payload: bytes | str,
        qos: int = 1,
        user_properties: list[tuple[str, str]] | None = None,
        timeout: float = 30.0,
    ) -> None:
        """Publish once; return when the broker acknowledged it (paho sends
        it again by itself after a reconnection)."""
        properties = None
        if user_properties:
            properties = Properties(PacketTypes.PUBLISH)
            properties.UserProperty = user_properties
        # Not under our lock: paho calls on_publish (which takes it) holding
        # its own, which publish() takes too; _acked keeps an early PUBACK.
        info = self.client.publish(topic, payload, qos=qos, properties=properties)
        if qos == 0:
            return
        with self._lock:
            if not self._lock.wait_for(lambda: info.mid in self._acked, timeout):
                raise TimeoutError(f"the broker did not acknowledge a message on {topic} within {timeout:g} s")
            self._acked.discard(info.mid)

    def close(self) -> None:
        self.client.disconnect()
        self.client.loop_stop()

    def __enter__(self) -> Publisher:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


# --- a service consuming from the broker (tests that run ``serve`` as a process) ---

READY_TIMEOUT_S = 30.0


def mqtt_settings(url: str, prefix: str, template: str = "${service}${servicePath}", **extra) -> dict:
    """App settings (``client_factory``) to consume ``prefix/#`` under a
    client id of the test's own, the tenant and service path in the topic
    after ``prefix/`` as ``template`` says."""
    return {
        "mqtt_url": url,
        "mqtt_client_id": unique_client_id("svc"),
        "mqtt_topics": f"{prefix}/#",
        "mqtt_topic_template": f"{prefix}/{template}",
        **extra,
    }


def mqtt_args(url: str, prefix: str, client_id: str, *extra: str) -> list[str]:
    """``serve`` flags to consume ``prefix/#``, the tenant and service path in the topic."""
    return [
        "--mqtt-url",
        url,
        "--mqtt-client-id",
        client_id,
        "--mqtt-topics",
        f"{prefix}/#",
        "--mqtt-topic-template",
        f"{prefix}/${{service}}${{servicePath}}",
        *extra,
    ]


def ready(server: ServerProcess, timeout: float = READY_TIMEOUT_S) -> ServerProcess:
    """Wait until the service is subscribed (``/health`` passes): before
    that the broker queues nothing for a new session."""
    deadline = time.monotonic() + timeout
    while True:
        report = httpx.get(server.url + "/health", timeout=5).json()
        if report["status"] == "pass":
            return server
        assert time.monotonic() < deadline, f"MQTT never came up: {report}\n{server.output()[-3000:]}"
        time.sleep(0.05)


def mqtt_outcome(server: ServerProcess, outcome: str) -> int:
    """This process's count of MQTT messages stored, rejected, redelivered
    or poisoned (``/metrics``)."""
    prefix = f'tsdb_mqtt_messages_total{{outcome="{outcome}"}} '
    metrics = httpx.get(server.url + "/metrics", timeout=10).text
    return int(float(next(line for line in metrics.splitlines() if line.startswith(prefix)).split()[-1]))
