"""A stand-in NGSI-LD broker that keeps context source registrations and
forwards temporal reads to them, for ``tsdb-service register``'s tests.

It does what a broker with distributed operations does for the temporal API
(ETSI GS CIM 009 clause 4.3.6), and nothing else:

* ``POST /ngsi-ld/v1/csourceRegistrations``: checks the registration the
  way a strict broker does (``type``, ``information`` with entities,
  ``endpoint`` a URI, a known ``mode``, known ``operations``), keeps it per
  ``NGSILD-Tenant``, answers 201 with ``Location``;
* ``GET /ngsi-ld/v1/csourceRegistrations?type=...``: the tenant's
  registrations for those types, paged (``limit``, ``offset``,
  ``NGSILD-Results-Count`` with ``count=true``); without a selector 400;
* ``GET /ngsi-ld/v1/temporal/entities[/{id}]``: it holds no history of its
  own, so it forwards the request (query string, ``Link``, tenant) to every
  registration of the tenant whose operations include the temporal read
  and whose types match, and merges the entities they answer.

``listing_fails`` makes the listing answer 500 (a broker that cannot tell
what it has).
"""

from __future__ import annotations

import itertools

import httpx
from starlette.applications import Starlette
from starlette.requests import Request
from starlette.responses import JSONResponse, PlainTextResponse, Response
from starlette.routing import Route

MODES = ("inclusive", "exclusive", "redirect", "auxiliary")
OPERATIONS = ("retrieveTemporal", "queryTemporal", "retrieveEntity", "queryEntity", "retrieveOps", "federationOps")
BASE = "/ngsi-ld/v1"


def _problem(status: int, ld_type: str, detail: str) -> JSONResponse:
    body = {"type": f"https://uri.etsi.org/ngsi-ld/errors/{ld_type}", "title": ld_type, "detail": detail}
    return JSONResponse(body, status)


class LdRegistry:
    page = 2  # small pages: the listing is followed past the first

    def __init__(self) -> None:
        self.registrations: dict[str, list[dict]] = {}
        self.received: list[tuple[str, dict]] = []  # (tenant, body) of every POST
        self.listing_fails = False
        self.url = ""
        self._ids = itertools.count(1)
        self.app = Starlette(
            routes=[
                Route(f"{BASE}/csourceRegistrations", self.create, methods=["POST"]),
                Route(f"{BASE}/csourceRegistrations", self.list, methods=["GET"]),
                Route(f"{BASE}/temporal/entities", self.temporal, methods=["GET"]),
                Route(f"{BASE}/temporal/entities/{{entity_id:path}}", self.temporal, methods=["GET"]),
            ]
        )

    @staticmethod
    def tenant(request: Request) -> str:
        return request.headers.get("ngsild-tenant", "")

    async def create(self, request: Request) -> Response:
        body = await request.json()
        self.received.append((self.tenant(request), body))
        information = body.get("information")
        if body.get("type") != "ContextSourceRegistration" or not isinstance(information, list) or not information:
            return _problem(400, "BadRequestData", "a ContextSourceRegistration with information")
        if not all(isinstance(i, dict) and i.get("entities") for i in information):
            return _problem(400, "BadRequestData", "each RegistrationInfo names entities here")
        endpoint = body.get("endpoint")
        if not isinstance(endpoint, str) or not endpoint.startswith(("http://", "https://")):
            return _problem(400, "BadRequestData", "endpoint must be an http(s) URI")
        if body.get("mode", "inclusive") not in MODES or not set(body.get("operations", [])) <= set(OPERATIONS):
            return _problem(400, "BadRequestData", "unknown mode or operations")
        reg_id = f"urn:ngsi-ld:ContextSourceRegistration:{next(self._ids)}"
        self.registrations.setdefault(self.tenant(request), []).append({"id": reg_id, **body})
        return Response(status_code=201, headers={"Location": f"{BASE}/csourceRegistrations/{reg_id}"})

    async def list(self, request: Request) -> Response:
        if self.listing_fails:
            return PlainTextResponse("database down", status_code=500)
        wanted = {t for t in request.query_params.get("type", "").split(",") if t}
        if not wanted:
            return _problem(400, "BadRequestData", "a registration query needs type, attrs, q or geoQ")
        found = [r for r in self.registrations.get(self.tenant(request), []) if wanted & _types(r)]
        offset = int(request.query_params.get("offset", 0))
        limit = min(int(request.query_params.get("limit", 20)), self.page)
        headers = {"NGSILD-Results-Count": str(len(found))} if request.query_params.get("count") == "true" else {}
        return JSONResponse(found[offset : offset + limit], headers=headers)

    async def temporal(self, request: Request) -> Response:
        """Forward to the matching registrations and merge their entities."""
        operation = "retrieveTemporal" if "entity_id" in request.path_params else "queryTemporal"
        wanted = set(request.query_params.get("type", "").split(",")) - {""}
        headers = {k: v for k, v in request.headers.items() if k.lower() in ("link", "ngsild-tenant", "accept")}
        merged: dict[str, dict] = {}
        async with httpx.AsyncClient(timeout=10) as client:
            for reg in self.registrations.get(self.tenant(request), []):
                if operation not in reg.get("operations", []) or (wanted and not wanted & _types(reg)):
                    continue
                target = reg["endpoint"].rstrip("/") + request.url.path
                answer = await client.get(target, params=list(request.query_params.multi_items()), headers=headers)
                if answer.status_code != 200:
                    continue
                body = answer.json()
                for item in body if isinstance(body, list) else [body]:
                    merged.setdefault(item["id"], {}).update(item)
        if operation == "retrieveTemporal":
            found = merged.get(request.path_params["entity_id"])
            return JSONResponse(found) if found else _problem(404, "ResourceNotFound", "no such entity")
        return JSONResponse(list(merged.values()))


def _types(registration: dict) -> set[str]:
    return {e.get("type") for info in registration.get("information", []) for e in info.get("entities", [])}
