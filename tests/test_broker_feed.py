"""Orion → subscription → notification, end to end, against a stand-in broker.

No container engine runs here, so neither Orion nor Orion-LD can: the
stand-in below does what this path needs of them, the way they document it.
It keeps subscriptions per tenant, takes entity updates (NGSIv2
``POST /v2/op/update``, NGSI-LD ``POST /ngsi-ld/v1/entityOperations/upsert``),
merges them into the entity it holds and notifies every matching
subscription with the whole entity (``normalized``; NGSI-LD with the
``receiverInfo`` headers). What is checked is our side of the path:
``tsdb-service subscribe`` makes subscriptions that route the demo's
entities back to us, ``tsdb-service demo --broker`` sends updates a broker
accepts, and what the broker relays is stored where the dashboards and the
explorer look (tenant and service path), over both APIs. docker-compose.yml
runs the same two commands against real images (tests/test_containers.py).
"""

from __future__ import annotations

import httpx
import pytest

from tests.support.server import ServerProcess
from tests.support.standins import StandInOrion, served
from tsdb_service.broker.updates import ld_entity
from tsdb_service.cli.main import main
from tsdb_service.usecases.registry import SIMULATORS


@pytest.fixture
def orion():
    with served(StandInOrion()) as stand_in:
        yield stand_in


@pytest.fixture
def service(tmp_path):
    server = ServerProcess(tmp_path / "fed.duckdb").start()
    try:
        yield server
    finally:
        server.terminate()


def _feed(orion, service, *extra: str) -> None:
    demo = ["demo", "--no-serve", "--url", service.url, "--broker", orion.url, "--duration", "2", "--speedup", "30"]
    assert main([*demo, "--use-case", "lawnmower", "--seed", "7", *extra]) == 0


@pytest.mark.parametrize("api", ["NGSIv2", "NGSI-LD"])
def test_the_demo_through_a_broker_lands_where_the_dashboards_look(orion, service, capsys, api):
    ld = ["--ngsi-ld"] if api == "NGSI-LD" else []
    notify = service.url + ("/ngsi-ld/v1/notify" if ld else "/v2/notify")
    assert main(["subscribe", "--broker", orion.url, "--use-case", "lawnmower", "--notify-url", notify, *ld]) == 0
    assert "201 Created" in capsys.readouterr().out
    _feed(orion, service, *ld)
    said = capsys.readouterr().out
    assert f"updating the entities in {'Orion-LD (NGSI-LD)' if ld else 'Orion (NGSIv2)'}" in said
    assert orion.notified and set(orion.notified) == {200}, orion.notified
    mower = SIMULATORS["lawnmower"]
    headers = {"Fiware-Service": mower.tenancy.service, "Fiware-ServicePath": mower.tenancy.service_path}
    (entity,) = httpx.get(service.url + "/v2/entities", headers=headers, timeout=10).json()
    assert entity["id"] == "urn:ngsiv2:ROS2System:Lawnmower01"
    speed = httpx.get(
        f"{service.url}/v2/entities/{entity['id']}/attrs/odom(twist.twist.linear.x)",
        params={"lastN": 1000},
        headers=headers,
        timeout=10,
    ).json()
    assert len(speed["values"]) == len(orion.notified)  # one sample per notification the broker sent


def test_running_subscribe_twice_keeps_one_ld_subscription(orion, capsys):
    args = ["subscribe", "--broker", orion.url, "--use-case", "drone", "--ngsi-ld", "--notify-url", "http://x/n"]
    assert main(args) == 0 and main(args) == 0
    assert "already subscribed" in capsys.readouterr().out
    (only,) = orion.subscriptions[("drone", "ld")]
    assert only["type"] == "Subscription" and only["notification"]["endpoint"]["uri"] == "http://x/n"


def test_ngsi_ld_entities_keep_observed_at_and_geometry():
    entity = {
        "id": "urn:a",
        "type": "Robot",
        "TimeInstant": {"type": "DateTime", "value": "2025-06-02T09:00:01.000Z", "metadata": {}},
        "location": {"type": "geo:json", "value": {"type": "Point", "coordinates": [8.9, 48.7]}, "metadata": {}},
        "odom": {
            "type": "Object",
            "value": {"x": 1},
            "metadata": {"TimeInstant": {"type": "DateTime", "value": "2025-06-02T09:00:00.000Z"}},
        },
    }
    assert ld_entity(entity) == {
        "id": "urn:a",
        "type": "Robot",
        "location": {"type": "GeoProperty", "value": {"type": "Point", "coordinates": [8.9, 48.7]}},
        "odom": {"type": "Property", "value": {"x": 1}, "observedAt": "2025-06-02T09:00:00.000Z"},
    }


def test_ngsi_ld_without_a_broker_is_refused(tmp_path):
    from tests.support.cli import assert_usage_error, run_cli

    assert_usage_error(run_cli("demo", "--ngsi-ld", "--duration", "1", cwd=tmp_path), "--ngsi-ld needs --broker")
    assert list(tmp_path.iterdir()) == []


def test_an_unreachable_broker_is_one_line(tmp_path):
    from tests.support.cli import assert_usage_error, run_cli
    from tests.support.server import free_port

    url = f"http://127.0.0.1:{free_port()}"
    done = run_cli("demo", "--no-serve", "--broker", url, "--duration", "1", cwd=tmp_path)
    assert_usage_error(done, f"cannot reach the broker at {url}")
