"""The ceilings: a bare FastAPI app.

``POST /v2/notify`` parses the JSON body and answers 200 ``{}``; ``GET
/v2/entities/{id}/attrs/{attr}`` answers a ready-made lastN=100 body (the
shape and size of ours). Neither stores nor reads anything, so what they
reach under the same uvicorn settings is the most any FastAPI service on this
machine could take: the ingest ceiling and the bare GET ceiling.

Run it the way ``benchmarks/ingest.py`` and ``benchmarks/compare.py`` do::

    .venv/bin/python -m uvicorn --app-dir benchmarks bare_app:app \\
        --host 127.0.0.1 --port 8669 --loop uvloop --http httptools \\
        --no-access-log --workers 1
"""

from __future__ import annotations

import json
from datetime import UTC, datetime, timedelta

from fastapi import FastAPI, Request, Response

app = FastAPI(title="bare ceilings")

_START = datetime(2024, 5, 1, tzinfo=UTC)
_LASTN_100 = json.dumps(
    {
        "attrName": "batteryLevel",
        "entityId": "urn:ngsi-ld:Lawnmower:q00",
        "entityType": "Lawnmower",
        "index": [(_START + timedelta(minutes=m)).strftime("%Y-%m-%dT%H:%M:%S.000+00:00") for m in range(1340, 1440)],
        "values": [100 - m / 10 for m in range(100)],
    },
    separators=(",", ":"),
).encode()


@app.post("/v2/notify")
async def notify(request: Request) -> dict:
    await request.json()
    return {}


@app.get("/v2/entities/{entity_id}/attrs/{attr}")
async def lastn(entity_id: str, attr: str) -> Response:
    return Response(_LASTN_100, media_type="application/json")


# --- the raw ASGI ceiling ------------------------------------------------------------------------
#
# The same two answers with no framework at all: what the HTTP server itself
# (uvicorn or granian) and the event loop can do on this machine. A route of
# ours that is served ahead of the framework (``POST /v2/notify``) is held
# against this ceiling, as is the hottest read (lastN).

_EMPTY = b"{}"
_JSON_HEADERS_EMPTY = [(b"content-type", b"application/json"), (b"content-length", b"2")]
_JSON_HEADERS_LASTN = [(b"content-type", b"application/json"), (b"content-length", str(len(_LASTN_100)).encode())]


async def raw_app(scope, receive, send) -> None:
    if scope["type"] == "lifespan":
        while True:
            message = await receive()
            if message["type"] == "lifespan.startup":
                await send({"type": "lifespan.startup.complete"})
            elif message["type"] == "lifespan.shutdown":
                await send({"type": "lifespan.shutdown.complete"})
                return
    if scope["type"] != "http":
        return
    if scope["method"] == "POST" and scope["path"] == "/v2/notify":
        chunks, more = [], True
        while more:
            message = await receive()
            chunks.append(message.get("body", b""))
            more = message.get("more_body", False)
        json.loads(b"".join(chunks))
        await send({"type": "http.response.start", "status": 200, "headers": _JSON_HEADERS_EMPTY})
        await send({"type": "http.response.body", "body": _EMPTY})
    elif scope["method"] == "GET" and (scope["path"].startswith("/v2/entities/") or scope["path"] == "/health"):
        await send({"type": "http.response.start", "status": 200, "headers": _JSON_HEADERS_LASTN})
        await send({"type": "http.response.body", "body": _LASTN_100})
    else:
        await send({"type": "http.response.start", "status": 404, "headers": _JSON_HEADERS_EMPTY})
        await send({"type": "http.response.body", "body": _EMPTY})
