"""Orion → MQTT → tsdb-service, end to end (issue 31).

``tsdb-service subscribe --mqtt`` makes subscriptions that notify over MQTT;
a stand-in broker (tests/test_broker_feed.py's, publishing the way Orion and
Orion-LD document: ``mqttCustom`` with its topic macros filled in, the bare
body; Orion-LD's endpoint ``mqtt://host:port/topic`` with the
``{"metadata", "body"}`` envelope) relays the demo's entity updates to the
real mosquitto, and a real ``tsdb-service serve`` consumes them. Running
``subscribe --mqtt`` twice keeps one subscription, and it prints the topic
each use case arrives on. ``demo --via mqtt``: tests/test_demo_via_mqtt.py.
"""

from __future__ import annotations

from urllib.parse import urlsplit

import orjson
import pytest

from tests.support.mosquitto import Publisher, ready
from tests.support.mqtt_service import settled
from tests.support.server import ServerProcess
from tests.support.standins import StandInOrion, served
from tsdb_service.cli.main import main
from tsdb_service.usecases.registry import SIMULATORS


class MqttOrion(StandInOrion):
    """The stand-in, notifying over MQTT where a subscription says so."""

    def __init__(self, broker_url: str):
        super().__init__()
        self.publisher = Publisher(broker_url)
        self.published: list[str] = []

    async def deliver(self, sub: dict, tenancy, body: dict, headers: dict) -> None:
        notification = sub["notification"]
        if "mqttCustom" in notification:  # Orion: macros in the topic, the bare body, the subscription's QoS
            custom = notification["mqttCustom"]
            topic = custom["topic"].replace("${service}", tenancy[0]).replace("${servicePath}", tenancy[1])
            self.publisher.publish(topic, orjson.dumps(body), qos=custom["qos"])
        elif notification.get("endpoint", {}).get("uri", "").startswith("mqtt://"):  # Orion-LD: the envelope
            endpoint = notification["endpoint"]
            topic = urlsplit(endpoint["uri"]).path.lstrip("/")
            qos = int(next(i["value"] for i in endpoint["notifierInfo"] if i["key"] == "MQTT-QoS"))
            metadata = {"Content-Type": "application/json", "Ngsild-Attribute-Format": "Normalized", **headers}
            self.publisher.publish(topic, orjson.dumps({"metadata": metadata, "body": body}), qos=qos)
        else:
            await super().deliver(sub, tenancy, body, headers)
            return
        self.published.append(topic)
        self.notified.append(200)


@pytest.fixture
def orion(mosquitto):
    stand_in = MqttOrion(mosquitto.url)
    with served(stand_in) as running:
        yield running
    stand_in.publisher.close()


@pytest.fixture(scope="module")
def service(tmp_path_factory, mosquitto):
    """The service consuming the default topics (tsdb/#): only this module publishes there."""
    folder = tmp_path_factory.mktemp("mqtt-feed")
    server = ServerProcess(folder / "fed.duckdb", args=["--mqtt-url", mosquitto.url, "--mqtt-client-id", "feed"])
    ready(server.start())
    try:
        yield server
    finally:
        server.terminate()


@pytest.mark.parametrize(("api", "use_case"), [("NGSIv2", "lawnmower"), ("NGSI-LD", "warehouse")])
def test_subscribe_mqtt_then_the_broker_feeds_the_service_over_mqtt(orion, service, mosquitto, capsys, api, use_case):
    ld = ["--ngsi-ld"] if api == "NGSI-LD" else []
    subscribe = ["subscribe", "--broker", orion.url, "--use-case", use_case, "--mqtt", mosquitto.url, *ld]
    assert main(subscribe) == 0 and main(subscribe) == 0  # the second keeps the first
    out = capsys.readouterr().out
    assert "201 Created" in out and "already subscribed" in out, out
    sim = SIMULATORS[use_case]
    assert f"notify over MQTT: {mosquitto.url}, topic tsdb/${{service}}${{servicePath}}" in out
    assert out.count(f"published on topic tsdb/{sim.tenancy.service}{sim.tenancy.service_path}") == 2
    ((_, subs),) = [(k, v) for k, v in orion.subscriptions.items() if k[0] == sim.tenancy.service]
    (sub,) = subs
    if ld:
        endpoint = sub["notification"]["endpoint"]
        assert endpoint["uri"] == f"{mosquitto.url}/tsdb/{sim.tenancy.service}{sim.tenancy.service_path}"
        assert endpoint["notifierInfo"] == [{"key": "MQTT-QoS", "value": "1"}]
    else:
        assert sub["notification"]["mqttCustom"] == {
            "url": mosquitto.url,
            "topic": "tsdb/${service}${servicePath}",
            "qos": 1,
        }
        assert "http" not in sub["notification"]
    _feed_case(orion, service, use_case, *ld)
    assert orion.published and all(
        t == f"tsdb/{sim.tenancy.service}{sim.tenancy.service_path}" for t in orion.published
    )
    assert settled(service, sim, len(orion.published)) == len(orion.published)


def _feed_case(orion, service, use_case: str, *extra: str) -> None:
    demo = ["demo", "--no-serve", "--url", service.url, "--broker", orion.url, "--duration", "1", "--speedup", "30"]
    assert main([*demo, "--use-case", use_case, "--seed", "7", *extra]) == 0


def test_mqtt_and_notify_url_exclude_each_other(orion, mosquitto, capsys):
    base = ["subscribe", "--broker", orion.url, "--use-case", "drone"]
    assert main([*base, "--mqtt", mosquitto.url, "--notify-url", "http://x/v2/notify"]) == 2
    assert main([*base, "--mqtt", "http://broker:1883"]) == 2
    assert main([*base, "--mqtt", mosquitto.url, "--ngsi-ld", "--mqtt-topic", "t/${id}"]) == 2
    err = capsys.readouterr().err
    assert "one or the other" in err and "mqtt://host:1883" in err and "Orion-LD fills in no topic macros" in err
    assert not orion.subscriptions
