"""``tsdb-service demo --via mqtt`` (issue 31): the demo's notifications over MQTT.

The demo publishes each notification as Orion's ``mqttCustom`` would (the
bare body at QoS 1 on ``tsdb/SERVICE/PATH``), to a broker given with
``--mqtt-url`` or to a Mosquitto it starts beside its file, and a real
``tsdb-service serve`` consumes them: every notification the broker
acknowledged is stored. Without a broker to use, or with one that does not
answer, it says so in one ``error:`` line (exit 2) and creates nothing.
"""

from __future__ import annotations

import re

import pytest

from tests.support.mosquitto import ready
from tests.support.mqtt_service import settled, stored_notifications
from tests.support.server import ServerProcess
from tsdb_service.cli.main import main
from tsdb_service.demo.mosquitto import free_port
from tsdb_service.usecases.registry import SIMULATORS


@pytest.fixture(scope="module")
def service(tmp_path_factory, mosquitto):
    """A service consuming the default topics (tsdb/#) under its own client id."""
    folder = tmp_path_factory.mktemp("demo-via-mqtt")
    server = ServerProcess(folder / "fed.duckdb", args=["--mqtt-url", mosquitto.url, "--mqtt-client-id", "demo-via"])
    ready(server.start())
    try:
        yield server
    finally:
        server.terminate()


def test_the_demo_publishes_over_mqtt_to_a_running_service(service, mosquitto, capsys):
    sim = SIMULATORS["drone"]
    before = stored_notifications(service, sim)
    demo = ["demo", "--no-serve", "--url", service.url, "--via", "mqtt", "--mqtt-url", mosquitto.url]
    assert main([*demo, "--use-case", "drone", "--duration", "1", "--speedup", "30", "--seed", "3"]) == 0
    out = capsys.readouterr().out
    sent = int(re.search(r"(\d+) notifications sent, (\d+) acknowledged, 0 failed", out)[1])
    assert sent > 0 and settled(service, sim, before + sent) == before + sent


def test_the_demo_over_mqtt_starts_its_own_mosquitto_and_service(tmp_path, capsys):
    db = tmp_path / "demo.duckdb"
    port = free_port()
    args = ["demo", "--via", "mqtt", "--db", str(db), "--port", str(port), "--use-case", "warehouse"]
    assert main([*args, "--duration", "1", "--speedup", "30", "--seed", "5"]) == 0
    out = capsys.readouterr().out
    assert "publishing to the MQTT broker mqtt://127.0.0.1:" in out
    sent = int(re.search(r"(\d+) notifications sent, \1 acknowledged, 0 failed", out)[1])
    assert "the broker keeps the rest" not in out  # the demo waited until the service had them all
    import duckdb

    with duckdb.connect(str(db), read_only=True) as con:
        (rows,) = con.execute("SELECT count(DISTINCT rid) FROM samples_all").fetchone()
    assert rows == sent


def test_via_mqtt_needs_a_broker_it_can_name(tmp_path, capsys):
    base = ["demo", "--via", "mqtt", "--db", str(tmp_path / "x.duckdb"), "--duration", "1"]
    assert main([*base, "--no-serve"]) == 2
    assert main([*base, "--broker", "http://orion:1026"]) == 2
    assert main(["demo", "--mqtt-url", "mqtt://b:1883", "--duration", "1"]) == 2
    err = capsys.readouterr().err
    assert "--no-serve needs --mqtt-url" in err and "--broker needs --mqtt-url" in err and "needs --via mqtt" in err
    assert list(tmp_path.iterdir()) == []


def test_via_mqtt_without_a_broker_or_mosquitto_is_one_error_line(tmp_path, capsys, monkeypatch):
    import tsdb_service.demo.mosquitto as local

    base = ["demo", "--via", "mqtt", "--db", str(tmp_path / "x.duckdb"), "--duration", "1"]
    monkeypatch.setattr(local, "find_mosquitto", lambda: None)
    assert main(base) == 2
    assert main([*base, "--mqtt-url", f"mqtt://127.0.0.1:{free_port()}"]) == 2  # nothing listens there
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 2 and all(line.startswith("error: ") for line in err), err
    assert "install Mosquitto" in err[0] and "cannot reach the MQTT broker" in err[1]
    assert list(tmp_path.iterdir()) == []


def test_the_demo_publisher_keeps_up_with_concurrent_publications(mosquitto):
    """Eight senders, 4,000 publications, each awaited until acknowledged:
    paho acknowledges on its own thread while the senders publish, which
    once deadlocked (our lock held around paho's publish, paho's around our
    callback)."""
    import asyncio
    import threading

    from tsdb_service.demo.mqtt import MqttPublisher

    publisher = MqttPublisher(mosquitto.url)

    async def sender() -> None:
        for _ in range(500):
            await publisher.publish("demo-stress/x", b"{}")

    async def all_senders() -> None:
        await asyncio.gather(*(sender() for _ in range(8)))

    # On a thread of its own: a deadlock blocks the event loop, which no
    # asyncio timeout can then interrupt; it fails here instead of hanging.
    done = threading.Thread(target=asyncio.run, args=(all_senders(),), daemon=True)
    done.start()
    done.join(60)
    assert not done.is_alive(), "the senders are stuck"
    publisher.close()
