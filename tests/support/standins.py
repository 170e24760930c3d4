"""Stand-in brokers served over real HTTP (uvicorn in a thread on 127.0.0.1).

Neither Orion nor Orion-LD runs here (no container engine), so these do what
a test needs of them, the way they document it: ``StandInBroker`` keeps
subscriptions per tenant (201 + ``Location``), refuses a bad ``idPattern``
with Orion's error shape and notifies like Orion; ``StandInOrion`` also takes
entity updates (NGSIv2 ``op/update``, NGSI-LD batch upsert) and notifies every
matching subscription with the whole entity. ``served`` runs one and sets its
``url`` (through ``tests.support.serving``).
"""

from __future__ import annotations

import itertools
import re
from contextlib import contextmanager
from datetime import UTC, datetime

import httpx
from starlette.applications import Starlette
from starlette.requests import Request
from starlette.responses import JSONResponse, PlainTextResponse, Response
from starlette.routing import Route

from tests.support.serving import serving


class StandInBroker:
    """What the helper needs of Orion: POST/GET /v2/subscriptions and notifying."""

    def __init__(self) -> None:
        self.subscriptions: dict[tuple[str, str], list[dict]] = {}
        self._ids = itertools.count(0x65F0C3D7E3B8A4C1E9A57200)
        self.app = Starlette(
            routes=[
                Route("/v2", self.index),
                Route("/v2/subscriptions", self.create, methods=["POST"]),
                Route("/v2/subscriptions", self.list, methods=["GET"]),
                Route("/broken/v2/subscriptions", self.broken, methods=["POST"]),
                Route("/moved/v2/subscriptions", self.moved, methods=["POST"]),
            ]
        )

    @staticmethod
    def tenant(request: Request) -> tuple[str, str]:
        return (request.headers.get("fiware-service", "").lower(), request.headers.get("fiware-servicepath", "/"))

    async def index(self, request: Request) -> Response:
        return JSONResponse({"entities_url": "/v2/entities", "subscriptions_url": "/v2/subscriptions"})

    async def create(self, request: Request) -> Response:
        body = await request.json()
        entities = body.get("subject", {}).get("entities")
        if not entities:
            return JSONResponse({"error": "BadRequest", "description": "no subject entities specified"}, 400)
        if any(e.get("idPattern") == "(" for e in entities):
            return JSONResponse({"error": "BadRequest", "description": "Invalid regex for entity idPattern"}, 400)
        sub_id = f"{next(self._ids):024x}"
        self.subscriptions.setdefault(self.tenant(request), []).append({"id": sub_id, **body})
        return Response(status_code=201, headers={"Location": f"/v2/subscriptions/{sub_id}"})

    async def list(self, request: Request) -> Response:
        return JSONResponse(self.subscriptions.get(self.tenant(request), []))

    async def moved(self, request: Request) -> Response:
        return Response(status_code=307, headers={"Location": "/v2/subscriptions"})

    async def broken(self, request: Request) -> Response:
        return PlainTextResponse("database down", status_code=500)

    def notify(self, entity: dict) -> list[int]:
        """Notify ``entity`` (NGSIv2 normalized) to every subscription, as Orion would."""
        statuses = []
        for (service, path), subs in self.subscriptions.items():
            for sub in subs:
                target = sub["notification"].get("http") or sub["notification"]["httpCustom"]
                headers = {
                    "Content-Type": "application/json; charset=utf-8",
                    "Fiware-ServicePath": path,
                    "Ngsiv2-AttrsFormat": "normalized",
                    **target.get("headers", {}),
                }
                if service:
                    headers["Fiware-Service"] = service
                wanted = sub["notification"].get("attrs")
                data = {k: v for k, v in entity.items() if k in ("id", "type") or not wanted or k in wanted}
                body = {"subscriptionId": sub["id"], "data": [data]}
                statuses.append(httpx.post(target["url"], json=body, headers=headers, timeout=10).status_code)
        return statuses


@contextmanager
def served(stand_in):
    """A stand-in broker served by ``serving``, its URL set as ``stand_in.url``."""
    with serving(stand_in.app) as url:
        stand_in.url = url
        yield stand_in


class StandInOrion:
    """Subscriptions, entity updates and notifications of Orion and Orion-LD."""

    def __init__(self) -> None:
        self.subscriptions: dict[tuple[str, str], list[dict]] = {}
        self.entities: dict[tuple[str, str, str], dict] = {}
        self.notified: list[int] = []
        self.updates: list[tuple[str, dict[str, str], object]] = []  # (path?query, headers, body) of each update
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
        self.updates.append((request.url.path, dict(request.headers), body))
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
        self.updates.append((f"{request.url.path}?{request.url.query}", dict(request.headers), await request.json()))
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
