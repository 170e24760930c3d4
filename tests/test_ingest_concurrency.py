"""Concurrent notifications through several writer threads lose nothing.

Writers share one series-id space: the first notifications of a new entity,
arriving together, must all be acknowledged and all be stored, with one
series per attribute (a race here once answered 503, and Orion never retries).
"""

from __future__ import annotations

import asyncio

import httpx

HEADERS = {"Content-Type": "application/json", "Fiware-Service": "race"}
ROUNDS = 10
CONCURRENT = 16


def _body(entity: str, value: int) -> dict:
    return {
        "data": [
            {
                "id": entity,
                "type": "Racer",
                "a": {"type": "Number", "value": value},
                "b": {"type": "Number", "value": -value},
            }
        ]
    }


async def _burst(app) -> list[int]:
    async with app.router.lifespan_context(app):
        transport = httpx.ASGITransport(app=app)
        async with httpx.AsyncClient(transport=transport, base_url="http://tsdb") as client:
            statuses = []
            for r in range(ROUNDS):
                responses = await asyncio.gather(
                    *(client.post("/v2/notify", json=_body(f"E{r}", i), headers=HEADERS) for i in range(CONCURRENT))
                )
                statuses += [resp.status_code for resp in responses]
            counts = []
            for r in range(ROUNDS):
                resp = await client.get(f"/v2/entities/E{r}/attrs/a", headers=HEADERS)
                assert resp.status_code == 200, resp.text
                counts.append(len(resp.json()["values"]))
            listed = await client.get("/v2/entities", params={"type": "Racer"}, headers=HEADERS)
            assert len(listed.json()) == ROUNDS
    return statuses, counts


def test_first_notifications_of_an_entity_race_safely(app_factory, store_url):
    app = app_factory(store_url, writer_threads=3)
    statuses, counts = asyncio.run(_burst(app))
    assert statuses == [200] * (ROUNDS * CONCURRENT)
    assert counts == [CONCURRENT] * ROUNDS
