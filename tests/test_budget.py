"""Read budgets: one request cannot cost the process seconds and gigabytes.

The two costly cases of issue 12 at a small scale, with budgets lowered to
match: a SimpleJSON query of 50 wildcard targets over every sample, and
``/v2/attrs`` over a tenant with many series. Past a budget the answer is
``422 QueryTooLarge`` in the NGSI shape, naming the setting and how to
narrow the query; narrowed, the same question is answered.
"""

from __future__ import annotations

from datetime import UTC, datetime, timedelta

import pytest

from tsdb_service.core.model import AttrSample, EntitySample, Kind
from tsdb_service.write.ops import AppendSamples

T0 = datetime(2024, 5, 1, tzinfo=UTC)
ENTITIES = 20
SAMPLES = 100  # per entity: 2,000 samples per attribute
ATTRS = ("temperature", "humidity", "pressure")


def _load(client, entities: int = ENTITIES, samples: int = SAMPLES, attrs=ATTRS) -> None:
    batch = [
        EntitySample(
            "",
            "/",
            f"Room:{e:03d}",
            "Room",
            T0 + timedelta(seconds=s),
            [AttrSample(a, "Number", Kind.NUMBER, num=float(s)) for a in attrs],
        )
        for s in range(samples)
        for e in range(entities)
    ]
    client.app.state.store.write_sync([AppendSamples(batch)])


def _too_large(r, setting: str) -> None:
    assert r.status_code == 422, r.text
    body = r.json()
    assert body["error"] == "QueryTooLarge"
    assert setting in body["description"]
    assert "narrow the query" in body["description"]


def _simplejson(targets: int) -> dict:
    return {
        "range": {"from": "2024-05-01T00:00:00Z", "to": "2024-05-02T00:00:00Z"},
        "maxDataPoints": 100_000,
        "targets": [{"target": "*/temperature", "refId": f"R{i}"} for i in range(targets)],
    }


def test_simplejson_many_wildcard_targets(client_factory, store_url):
    with client_factory(store_url, read_max_rows=5_000) as client:
        _load(client)
        _too_large(client.post("/grafana/simplejson/query", json=_simplejson(50)), "TSDB_READ_MAX_ROWS")
        # Two targets of 2,000 samples each fit in 5,000.
        r = client.post("/grafana/simplejson/query", json=_simplejson(2))
        assert r.status_code == 200, r.text
        assert sum(len(frame["datapoints"]) for frame in r.json()) == 2 * ENTITIES * SAMPLES


def test_attrs_over_many_series(client_factory, store_url):
    with client_factory(store_url, read_max_series=50) as client:
        _load(client, samples=2)  # 20 entities x 3 attributes = 60 series
        _too_large(client.get("/v2/attrs"), "TSDB_READ_MAX_SERIES")
        _too_large(client.get("/grafana/infinity/entities"), "TSDB_READ_MAX_SERIES")
        r = client.get("/v2/attrs", params={"attrs": "temperature,humidity"})  # 40 series
        assert r.status_code == 200, r.text
        # Deletes are not reads: no budget.
        assert client.delete("/v2/types/Room").status_code == 204


def test_history_rows(client_factory, store_url):
    with client_factory(store_url, read_max_rows=150) as client:
        _load(client, entities=2, samples=100)
        # One series from the in-memory tails or SQL: the budget holds either way.
        assert client.get("/v2/entities/Room:000/attrs/temperature", params={"lastN": 150}).status_code == 200
        assert client.get("/v2/entities/Room:000/attrs/temperature").status_code == 200  # 100 samples
        _too_large(client.get("/v2/entities/Room:000"), "TSDB_READ_MAX_ROWS")  # 300 samples
        _too_large(client.get("/v2/types/Room/attrs/temperature"), "TSDB_READ_MAX_ROWS")  # 200
        r = client.get("/v2/types/Room/attrs/temperature", params={"lastN": 50})
        assert r.status_code == 200, r.text
        r = client.get("/v2/entities/Room:000", params={"aggrMethod": "avg"})
        assert r.status_code == 200, r.text
        _too_large(
            client.get("/v2/types/Room", params={"aggrMethod": "max", "aggrPeriod": "second"}), "TSDB_READ_MAX_ROWS"
        )  # 600 aggregate rows
        r = client.get("/v2/types/Room", params={"aggrMethod": "max", "aggrPeriod": "minute"})
        assert r.status_code == 200, r.text


def test_response_bytes(client_factory, store_url):
    with client_factory(store_url, read_max_response_bytes=4096) as client:
        _load(client, entities=2, samples=200)
        _too_large(client.get("/v2/types/Room"), "TSDB_READ_MAX_RESPONSE_BYTES")
        _too_large(
            client.get("/grafana/infinity/series", params={"attrs": "temperature"}), "TSDB_READ_MAX_RESPONSE_BYTES"
        )
        r = client.get("/v2/entities/Room:000/attrs/temperature", params={"lastN": 5})
        assert r.status_code == 200, r.text
        assert client.get("/health").status_code == 200


def test_wall_time(client_factory, store_url):
    with client_factory(store_url, read_max_seconds=1e-9) as client:
        _load(client, entities=2, samples=5)
        _too_large(client.get("/v2/types/Room"), "TSDB_READ_MAX_SECONDS")
        _too_large(client.post("/grafana/simplejson/query", json=_simplejson(1)), "TSDB_READ_MAX_SECONDS")
        _too_large(client.post("/v2/op/query", json={"entities": [{"idPattern": ".*"}]}), "TSDB_READ_MAX_SECONDS")
        assert client.get("/health").status_code == 200


@pytest.mark.parametrize("path", ["/v2/types/Room", "/v2/attrs", "/v2/entities"])
def test_default_budget_answers_ordinary_reads(client, path):
    _load(client)
    assert client.get(path).status_code == 200
