"""The demo's notifications over MQTT (``demo --via mqtt``), as Orion publishes them.

One paho-mqtt client publishes each notification body (no headers, as
Orion's ``mqttCustom``) at QoS 1 on the use case's topic
(``tsdb/SERVICE/SERVICE_PATH``, ``broker.subscriptions.MQTT_TOPIC`` filled
in); ``publish`` returns once the broker acknowledged it.
"""

from __future__ import annotations

import asyncio
import threading
from urllib.parse import urlsplit

import paho.mqtt.client as paho

from tsdb_service.core.config import MQTT_SCHEMES


class MqttPublisher:
    """One MQTT 5 client on ``url``, connected at once (OSError if nothing
    listens there); paho's thread sends and reconnects."""

    def __init__(self, url: str, client_id: str = ""):
        parts = urlsplit(url)
        self._client = paho.Client(paho.CallbackAPIVersion.VERSION2, client_id=client_id, protocol=paho.MQTTv5)
        if parts.scheme == "mqtts":
            self._client.tls_set()
        # Never held while calling paho: paho calls on_publish holding its own
        # lock, which publish() takes too (the other order deadlocks).
        self._lock = threading.Lock()
        self._waiting: dict[int, tuple[asyncio.AbstractEventLoop, asyncio.Future]] = {}
        self._early: dict[int, object] = {}  # acknowledged before publish() registered its waiter
        self._client.on_publish = self._on_publish
        self._client.reconnect_delay_set(1, 5)
        self._client.connect(parts.hostname or "localhost", parts.port or MQTT_SCHEMES.get(parts.scheme, 1883))
        self._client.loop_start()

    def _on_publish(self, client, userdata, mid, reason_code, properties) -> None:
        with self._lock:
            waiter = self._waiting.pop(mid, None)
            if waiter is None:
                self._early[mid] = reason_code
        if waiter is not None:
            loop, future = waiter
            loop.call_soon_threadsafe(_settle, future, reason_code)

    async def publish(self, topic: str, payload: bytes, timeout: float = 30.0) -> None:
        """Publish at QoS 1; return once the broker has it (RuntimeError if it
        refused it, TimeoutError if it did not answer within ``timeout``: a
        broker gone for good must not hang the demo, which counts it failed)."""
        loop = asyncio.get_running_loop()
        future = loop.create_future()
        info = self._client.publish(topic, payload, qos=1)
        with self._lock:  # its acknowledgement may have come already
            if info.mid in self._early:
                _settle(future, self._early.pop(info.mid))
            else:
                self._waiting[info.mid] = (loop, future)
        try:
            await asyncio.wait_for(future, timeout)
        finally:
            with self._lock:
                self._waiting.pop(info.mid, None)

    def close(self) -> None:
        self._client.disconnect()
        self._client.loop_stop()


def _settle(future: asyncio.Future, reason_code) -> None:
    if future.done():
        return
    if getattr(reason_code, "is_failure", False):
        future.set_exception(RuntimeError(f"the broker refused it: {reason_code}"))
    else:
        future.set_result(None)
