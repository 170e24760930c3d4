"""Through HTTP, lastN answers (one entity, or several of a type) with the
tail cache equal those without it,
while notifications (late ones included) and deletes interleave with reads."""

from __future__ import annotations

import random

H = {"Content-Type": "application/json", "Fiware-Service": "tail"}


def _post(client, i: int, t: int) -> None:
    body = {
        "data": [
            {
                "id": f"R{i % 3}",
                "type": "Robot",
                "speed": {"type": "Number", "value": i},
                "TimeInstant": {"type": "DateTime", "value": f"2024-05-01T10:{t // 60:02d}:{t % 60:02d}Z"},
            }
        ]
    }
    assert client.post("/v2/notify", json=body, headers=H).status_code == 200


def test_cached_and_uncached_answers_agree(client_factory, store_url_factory):
    rnd = random.Random(5)
    with (
        client_factory(store_url_factory("tail_on")) as cached,
        client_factory(store_url_factory("tail_off"), tail_cache_series=0) as plain,
    ):
        for step in range(250):
            roll = rnd.random()
            if roll < 0.5:
                t = step if rnd.random() < 0.85 else rnd.randint(0, step)
                for c in (cached, plain):
                    _post(c, step, t)
            elif roll < 0.52:
                params = {"type": "Robot", "toDate": f"2024-05-01T10:0{rnd.randint(0, 3)}:00Z"}
                path = f"/v2/entities/R{rnd.randint(0, 2)}"
                a, b = (c.delete(path, params=params, headers=H) for c in (cached, plain))
                assert a.status_code == b.status_code
            else:
                params = {"lastN": rnd.randint(1, 20)}
                if rnd.random() < 0.3:
                    params["fromDate"] = f"2024-05-01T10:0{rnd.randint(0, 3)}:{rnd.randint(0, 59):02d}Z"
                if rnd.random() < 0.3:
                    params["offset"] = rnd.randint(0, 5)
                path = rnd.choice([f"/v2/entities/R{rnd.randint(0, 2)}/attrs/speed", "/v2/types/Robot/attrs/speed"])
                a, b = cached.get(path, params=params, headers=H), plain.get(path, params=params, headers=H)
                assert (a.status_code, a.json()) == (b.status_code, b.json()), (path, params)
        tail = getattr(cached.app.state.store.memory, "tail", None)  # DuckDB only
        if tail is not None:
            assert tail.hits > 20, "the cached app never answered from its tail"
