"""Type-level lastN deeper than one tail (``/v2/types/T/attrs/A?lastN=N``
with N above the rows a tail keeps) answers from several series' tails when
they provably hold the newest N, and always equals the database's answer:
entities notified at uneven rates (so some tails are too short), late
samples, deletes, offsets and time windows interleave with the reads."""

from __future__ import annotations

import random

H = {"Content-Type": "application/json", "Fiware-Service": "deeptail"}
ENTITIES = 5


def _post(client, i: int, entity: int, t: int) -> None:
    body = {
        "data": [
            {
                "id": f"R{entity}",
                "type": "Robot",
                "speed": {"type": "Number", "value": i},
                "TimeInstant": {"type": "DateTime", "value": f"2024-05-01T10:{t // 60:02d}:{t % 60:02d}Z"},
            }
        ]
    }
    assert client.post("/v2/notify", json=body, headers=H).status_code == 200


def _entity(rnd: random.Random) -> int:
    """R0 is notified ten times as often as R4: its tail covers less time."""
    return min(ENTITIES - 1, int(rnd.expovariate(0.6)))


def test_deep_type_lastn_agrees_with_the_database(client_factory, store_url_factory):
    rnd = random.Random(11)
    with (
        client_factory(store_url_factory("deep_on"), tail_cache_rows=8) as cached,
        client_factory(store_url_factory("deep_off"), tail_cache_series=0) as plain,
    ):
        for step in range(400):
            roll = rnd.random()
            if roll < 0.55:
                t = step if rnd.random() < 0.9 else rnd.randint(0, step)
                entity = _entity(rnd)
                for c in (cached, plain):
                    _post(c, step, entity, t)
            elif roll < 0.56:
                params = {"type": "Robot", "toDate": f"2024-05-01T10:0{rnd.randint(0, 3)}:00Z"}
                path = f"/v2/entities/R{rnd.randint(0, ENTITIES - 1)}"
                a, b = (c.delete(path, params=params, headers=H) for c in (cached, plain))
                assert a.status_code == b.status_code
            else:
                params = {"lastN": rnd.choice([5, 9, 12, 20, 35])}
                if rnd.random() < 0.2:
                    params["fromDate"] = f"2024-05-01T10:0{rnd.randint(0, 5)}:{rnd.randint(0, 59):02d}Z"
                if rnd.random() < 0.3:
                    params["offset"] = rnd.randint(0, 6)
                path = "/v2/types/Robot/attrs/speed"
                a, b = cached.get(path, params=params, headers=H), plain.get(path, params=params, headers=H)
                assert (a.status_code, a.json()) == (b.status_code, b.json()), params
        tail = getattr(cached.app.state.store.memory, "tail", None)  # DuckDB only
        if tail is not None:
            assert tail.hits > 100, "the cached app never answered from its tails"


def test_deep_type_lastn_is_answered_from_memory(client_factory, store_url_factory):
    """Evenly notified entities: lastN=30 over 5 tails of 8 is answered
    without a database query once the tails are loaded (DuckDB)."""
    with client_factory(store_url_factory("deep_mem"), tail_cache_rows=8) as client:
        for step in range(60):
            _post(client, step, step % ENTITIES, step)
        path = "/v2/types/Robot/attrs/speed"
        first = client.get(path, params={"lastN": 30}, headers=H)
        assert first.status_code == 200
        values = sorted(v for e in first.json()["entities"] for v in e["values"])
        assert values == list(range(30, 60))
        if getattr(client.app.state.store.memory, "tail", None) is None:
            return  # PostgreSQL: no tails
        querier = client.app.state.store.querier()
        reads = []
        database = querier._fetch

        def counted(sql, params):
            reads.append(sql)
            return database(sql, params)

        querier._fetch = counted
        try:
            again = client.get(path, params={"lastN": 30}, headers=H)
        finally:
            del querier._fetch
        assert again.json() == first.json()
        assert reads == []
