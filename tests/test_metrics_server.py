"""``/metrics`` of a real uvicorn server process (the CLI's ``serve``), scraped
over HTTP after a known load, on both backends."""

from __future__ import annotations

import httpx
import orjson
from prometheus_client.parser import text_string_to_metric_families

from tests.support.server import ServerProcess

GOOD, BAD, QUERIES = 6, 2, 3


def notification(i: int) -> bytes:
    return orjson.dumps(
        {
            "subscriptionId": "s",
            "data": [
                {
                    "id": f"Door:{i}",
                    "type": "Door",
                    "TimeInstant": {"type": "DateTime", "value": "2024-05-01T10:00:00Z"},
                    "open": {"type": "Boolean", "value": i % 2 == 0},
                }
            ],
        }
    )


def test_a_served_process_reports_its_load(store_url_factory):
    headers = {"Content-Type": "application/json", "Fiware-Service": "site"}
    with ServerProcess(store_url_factory("metrics_server")) as server, httpx.Client(base_url=server.url) as http:
        for i in range(GOOD):
            assert http.post("/v2/notify", content=notification(i), headers=headers).status_code == 200
        for _ in range(BAD):
            assert http.post("/v2/notify", content=b'{"data": 1}', headers=headers).status_code == 400
        for i in range(QUERIES):
            assert http.get(f"/v2/entities/Door:{i}", headers=headers).status_code == 200
        scrape = http.get("/metrics")
    assert scrape.status_code == 200
    samples = {
        (s.name, tuple(sorted(s.labels.items()))): s.value
        for family in text_string_to_metric_families(scrape.text)
        for s in family.samples
    }
    assert samples[("tsdb_notifications_received_total", (("tenant", "site"),))] == GOOD + BAD
    assert samples[("tsdb_notifications_accepted_total", (("tenant", "site"),))] == GOOD
    assert samples[("tsdb_notifications_rejected_total", (("reason", "ParseError"), ("tenant", "site")))] == BAD
    query = (("method", "GET"), ("route", "/v2/entities/{entity_id}"), ("status", "200"))
    assert samples[("tsdb_http_request_duration_seconds_count", query)] == QUERIES
    assert samples[("tsdb_rejected_notifications", ())] == BAD
    assert samples[("tsdb_store_size_bytes", ())] > 0
    assert samples[("process_resident_memory_bytes", ())] > 0
