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

import itertools
import re
from datetime import UTC, datetime

import httpx
import pytest
from starlette.applications import Starlette
from starlette.requests import Request
from starlette.responses import JSONResponse, Response
from starlette.routing import Route

from tests.support.server import ServerProcess
from tests.test_subscribe_api import served
from tsdb_service.broker.updates import ld_entity
from tsdb_service.cli.main import main
from tsdb_service.usecases.registry import SIMULATORS


class StandInOrion:
    """Subscriptions, entity updates and notifications of Orion and Orion-LD."""

    def __init__(self) -> None:
        self.subscriptions: dict[tuple[str, str], list[dict]] = {}
        self.entities: dict[tuple[str, str, str], dict] = {}
        self.notified: list[int] = []
        self._ids = itertools.count(1)
        self.app = Starlette(
            routes=[
                Route("/version", lambda request: JSONResponse({"orion": {"version": "stand-in"}})),
                Route("/v2/subscriptions", self.create, methods=["POST"]),
                Route("/v2/subscriptions", self.listing, methods=["GET"]),
                Route("/ngsi-ld/v1/subscriptions", self.create, methods=["POST"]),
                Route("/ngsi-ld/v1/subscriptions", self.listing, methods=["GET"]),
                Route("/v2/op/update", self.update_v2, methods=["POST"]),
                Route("/ngsi-ld/v1/entityOperations/upsert", self.upsert_ld, methods=["POST"]),
            ]
        )

    @staticmethod
    def tenancy(request: Request) -> tuple[str, str]:
        if request.url.path.startswith("/ngsi-ld/"):
            return (request.headers.get("ngsild-tenant", ""), "ld")
        return (request.headers.get("fiware-service", ""), request.headers.get("fiware-servicepath", "/"))

    async def create(self, request: Request) -> Response:
        body = await request.json()
        ld = request.url.path.startswith("/ngsi-ld/")
        sub_id = f"urn:ngsi-ld:Subscription:{next(self._ids)}" if ld else f"{next(self._ids):024x}"
        self.subscriptions.setdefault(self.tenancy(request), []).append({"id": sub_id, **body})
        return Response(status_code=201, headers={"Location": f"{request.url.path}/{sub_id}"})

    async def listing(self, request: Request) -> Response:
        return JSONResponse(self.subscriptions.get(self.tenancy(request), []))

    async def update_v2(self, request: Request) -> Response:
        body = await request.json()
        assert body["actionType"] == "append"
        tenancy = self.tenancy(request)
        for entity in body["entities"]:
            whole = self._merge(tenancy, entity)
            for sub in self._matching(tenancy, whole, sub_key="subject"):
                headers = {
                    "Fiware-Service": tenancy[0],
                    "Fiware-ServicePath": tenancy[1],
                    "Ngsiv2-AttrsFormat": "normalized",
                }
                await self.deliver(sub, tenancy, {"subscriptionId": sub["id"], "data": [whole]}, headers)
        return Response(status_code=204)

    async def upsert_ld(self, request: Request) -> Response:
        assert request.query_params.get("options") == "update"
        assert "@context" not in (await request.body()).decode()  # application/json: the core context
        tenancy = self.tenancy(request)
        for entity in await request.json():
            assert all(a["type"] in ("Property", "GeoProperty") for k, a in entity.items() if k not in ("id", "type"))
            whole = self._merge(tenancy, entity)
            for sub in self._matching(tenancy, whole, sub_key=None):
                endpoint = sub["notification"]["endpoint"]
                headers = {
                    "NGSILD-Tenant": tenancy[0],
                    **{i["key"]: i["value"] for i in endpoint.get("receiverInfo", [])},
                }
                note = {
                    "id": f"urn:ngsi-ld:Notification:{next(self._ids)}",
                    "type": "Notification",
                    "subscriptionId": sub["id"],
                    "notifiedAt": datetime.now(UTC).isoformat().replace("+00:00", "Z"),
                    "data": [whole],
                }
                await self.deliver(sub, tenancy, note, headers)
        return Response(status_code=204)

    def _merge(self, tenancy, entity: dict) -> dict:
        key = (*tenancy, entity["id"])
        self.entities[key] = {**self.entities.get(key, {}), **entity}
        return self.entities[key]

    def _matching(self, tenancy, entity: dict, sub_key: str | None) -> list[dict]:
        found = []
        for sub in self.subscriptions.get(tenancy, []):
            selectors = sub[sub_key]["entities"] if sub_key else sub["entities"]
            if any(s["type"] == entity["type"] and re.search(s["idPattern"], entity["id"]) for s in selectors):
                found.append(sub)
        return found

    async def deliver(self, sub: dict, tenancy, body: dict, headers: dict) -> None:
        """Send a notification where the subscription says (over HTTP here)."""
        notification = sub["notification"]
        target = notification["endpoint"]["uri"] if "endpoint" in notification else notification["http"]["url"]
        await self._send(target, body, headers)

    async def _send(self, url: str, body: dict, headers: dict) -> None:
        async with httpx.AsyncClient(timeout=30) as client:
            response = await client.post(url, json=body, headers=headers)
        self.notified.append(response.status_code)


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
    from tests.test_cli_settings import assert_usage_error, run_cli

    assert_usage_error(run_cli("demo", "--ngsi-ld", "--duration", "1", cwd=tmp_path), "--ngsi-ld needs --broker")
    assert list(tmp_path.iterdir()) == []


def test_an_unreachable_broker_is_one_line(tmp_path):
    from tests.pg_cluster import free_port
    from tests.test_cli_settings import assert_usage_error, run_cli

    url = f"http://127.0.0.1:{free_port()}"
    done = run_cli("demo", "--no-serve", "--broker", url, "--duration", "1", cwd=tmp_path)
    assert_usage_error(done, f"cannot reach the broker at {url}")
