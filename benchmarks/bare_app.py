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
