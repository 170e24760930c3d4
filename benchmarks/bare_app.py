"""The ceiling for the ingest benchmark: a bare FastAPI app.

One route, ``POST /v2/notify``, that parses the JSON body and answers 200
``{}``. It stores nothing, so whatever throughput it reaches under the same
uvicorn settings is the most any FastAPI service on this machine could take.

Run it the way ``benchmarks/ingest.py`` does::

    .venv/bin/python -m uvicorn --app-dir benchmarks bare_app:app \\
        --host 127.0.0.1 --port 8669 --loop uvloop --http httptools \\
        --no-access-log --workers 1
"""

from __future__ import annotations

from fastapi import FastAPI, Request

app = FastAPI(title="bare notify ceiling")


@app.post("/v2/notify")
async def notify(request: Request) -> dict:
    await request.json()
    return {}
