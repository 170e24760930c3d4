"""``GET /metrics``: exact values after a known load, on both backends.

The load: good and bad notifications on two tenants (some without any time,
so their time index falls back to the reception time), history queries on
several entities, a layout registration (a write that is not a
notification). The scrape is parsed with prometheus_client's own parser.
"""

from __future__ import annotations

import orjson
import pytest
from prometheus_client.parser import text_string_to_metric_families

from tsdb_service.app import create_app
from tsdb_service.core.config import Settings
from tsdb_service.telemetry import OTHER, UNMATCHED, Metrics

GOOD_ALPHA, GOOD_BETA, BAD_BETA, QUERIES = 5, 2, 3, 4
ATTR_ROUTE = "/v2/entities/{entity_id}/attrs/{attr_name}"
JSON_HEADERS = {"Content-Type": "application/json"}


def scrape(client) -> dict[tuple[str, tuple], float]:
    """``(sample name, sorted labels) → value`` of one scrape."""
    response = client.get("/metrics")
    assert response.status_code == 200
    assert response.headers["content-type"].startswith("text/plain; version=0.0.4")
    return {
        (s.name, tuple(sorted(s.labels.items()))): s.value
        for family in text_string_to_metric_families(response.text)
        for s in family.samples
    }


def value(samples, name: str, **labels) -> float:
    return samples.get((name, tuple(sorted(labels.items()))), 0.0)


def total(samples, name: str, **labels) -> float:
    """Sum over every series of ``name`` whose labels include ``labels``."""
    return sum(v for (n, ls), v in samples.items() if n == name and set(labels.items()) <= set(ls))


def entity(i: int, timed: bool) -> dict:
    body = {"id": f"Robot:{i}", "type": "Robot", "temperature": {"type": "Number", "value": 20 + i}}
    if timed:
        body["TimeInstant"] = {"type": "DateTime", "value": f"2024-05-01T10:00:0{i}Z"}
    return body


def post(client, tenant: str, body: bytes | dict, headers: dict | None = None):
    content = body if isinstance(body, bytes) else orjson.dumps(body)
    return client.post(
        "/v2/notify", content=content, headers={**JSON_HEADERS, "Fiware-Service": tenant, **(headers or {})}
    )


def load(client) -> None:
    """The known load; every request's answer is checked, so counts are known."""
    for i in range(GOOD_ALPHA):  # the first two carry no time at all
        assert post(client, "alpha", {"subscriptionId": "s", "data": [entity(i, timed=i >= 2)]}).status_code == 200
    for i in range(GOOD_BETA):
        assert post(client, "beta", {"subscriptionId": "s", "data": [entity(i, timed=True)]}).status_code == 200
    assert post(client, "beta", b"{not json").status_code == 400
    assert post(client, "beta", b"[]").status_code == 400
    assert post(client, "beta", b"{}", {"Content-Type": "text/plain"}).status_code == 415
    layout = {"attrs": ["id", "temperature"], "entityType": "Robot"}
    assert (
        client.put("/v2/notify/subscriptions/s1", json=layout, headers={"Fiware-Service": "alpha"}).status_code == 200
    )
    for i in range(QUERIES):
        answer = client.get(f"/v2/entities/Robot:{i}/attrs/temperature", headers={"Fiware-Service": "alpha"})
        assert answer.status_code == 200, answer.text


def fallbacks_so_far() -> float:
    """The process-wide fallback counter, read without a scrape (which would
    cache the store sizes before the load)."""
    return Metrics().registry.get_sample_value("tsdb_time_index_fallbacks_total")


@pytest.fixture
def loaded(client):
    before = fallbacks_so_far()
    load(client)
    return client, scrape(client), before


def test_notifications_per_tenant_and_outcome(loaded):
    _, samples, _ = loaded
    assert value(samples, "tsdb_notifications_received_total", tenant="alpha") == GOOD_ALPHA
    assert value(samples, "tsdb_notifications_received_total", tenant="beta") == GOOD_BETA + BAD_BETA
    assert value(samples, "tsdb_notifications_accepted_total", tenant="alpha") == GOOD_ALPHA
    assert value(samples, "tsdb_notifications_accepted_total", tenant="beta") == GOOD_BETA
    assert value(samples, "tsdb_notifications_rejected_total", tenant="beta", reason="ParseError") == 2
    assert value(samples, "tsdb_notifications_rejected_total", tenant="beta", reason="UnsupportedMediaType") == 1
    assert total(samples, "tsdb_notifications_rejected_total", tenant="alpha") == 0
    assert total(samples, "tsdb_notifications_failed_total") == 0


def test_commit_latency_and_group_sizes(loaded):
    _, samples, _ = loaded
    good = GOOD_ALPHA + GOOD_BETA
    # Every accepted notification is in exactly one committed samples group.
    assert value(samples, "tsdb_commit_group_size_sum", kind="samples") == good
    commits = value(samples, "tsdb_commit_duration_seconds_count", kind="samples")
    assert 1 <= commits <= good
    assert value(samples, "tsdb_commit_group_size_count", kind="samples") == commits
    assert value(samples, "tsdb_commit_duration_seconds_sum", kind="samples") > 0
    assert value(samples, "tsdb_commit_group_size_sum", kind="rejected") == BAD_BETA
    assert value(samples, "tsdb_commit_group_size_sum", kind="layout") == 1
    assert value(samples, "tsdb_commit_duration_seconds_bucket", kind="samples", le="+Inf") == commits


def test_request_latency_is_labelled_by_route_template(loaded):
    _, samples, _ = loaded
    assert (
        value(samples, "tsdb_http_request_duration_seconds_count", route=ATTR_ROUTE, method="GET", status="200")
        == QUERIES
    )
    notify = {"route": "/v2/notify", "method": "POST"}
    assert value(samples, "tsdb_http_request_duration_seconds_count", status="200", **notify) == GOOD_ALPHA + GOOD_BETA
    assert value(samples, "tsdb_http_request_duration_seconds_count", status="400", **notify) == 2
    assert value(samples, "tsdb_http_request_duration_seconds_count", status="415", **notify) == 1
    routes = {dict(labels)["route"] for (name, labels) in samples if name.startswith("tsdb_http_request")}
    assert not any("Robot:" in route for route in routes), routes  # never the raw path


def test_unknown_paths_and_methods_stay_bounded(client):
    for i in range(3):
        assert client.get(f"/no/such/{i}").status_code == 404
    assert client.request("BREW", "/v2/entities").status_code == 405
    samples = scrape(client)
    assert value(samples, "tsdb_http_request_duration_seconds_count", route=UNMATCHED, method="GET", status="404") == 3
    assert (
        value(samples, "tsdb_http_request_duration_seconds_count", route="/v2/entities", method=OTHER, status="405")
        == 1
    )


def test_fallback_time_indexes(loaded):
    _, samples, before = loaded
    # Two alpha notifications had no time; the rejected ones never got that far.
    assert value(samples, "tsdb_time_index_fallbacks_total") - before == 2


def test_store_sizes_and_queue_depth(loaded):
    client, samples, _ = loaded
    assert value(samples, "tsdb_store_size_bytes") > 0
    assert value(samples, "tsdb_write_queue_depth") == 0
    assert value(samples, "tsdb_rejected_notifications") == BAD_BETA
    kept = client.get("/v2/notify/rejected", headers={"Fiware-Service": "beta"}).json()
    expected = sum(len(r["body"].encode()) + len(orjson.dumps(r["headers"])) for r in kept)
    assert value(samples, "tsdb_rejected_store_bytes") == expected


def test_tenant_labels_are_capped(store_url):
    from fastapi.testclient import TestClient

    app = create_app(Settings(db=store_url), metrics=Metrics(max_tenants=2))
    with TestClient(app) as client:
        for tenant in ("t1", "t2", "t3", "t4", "t1"):
            assert post(client, tenant, {"subscriptionId": "s", "data": [entity(1, True)]}).status_code == 200
        samples = scrape(client)
    accepted = {
        dict(labels)["tenant"]: v
        for (name, labels), v in samples.items()
        if name == "tsdb_notifications_accepted_total"
    }
    assert accepted == {"t1": 2, "t2": 1, OTHER: 2}


def test_each_app_counts_its_own_requests(client_factory, store_url_factory):
    with client_factory(store_url_factory("one")) as first, client_factory(store_url_factory("two")) as second:
        assert post(first, "alpha", {"subscriptionId": "s", "data": [entity(1, True)]}).status_code == 200
        assert total(scrape(second), "tsdb_notifications_received_total") == 0
        assert total(scrape(first), "tsdb_notifications_received_total") == 1


@pytest.mark.parametrize("ttl, seen", [(60.0, 0), (0.0, 1)])
def test_store_sizes_are_cached_between_scrapes(store_url, ttl, seen):
    """Within the cache time a scrape repeats the sizes it measured; with no
    cache it measures again."""
    from fastapi.testclient import TestClient

    with TestClient(create_app(Settings(db=store_url), metrics=Metrics(stats_ttl=ttl))) as client:
        assert value(scrape(client), "tsdb_rejected_notifications") == 0
        assert post(client, "beta", b"{not json").status_code == 400
        assert value(scrape(client), "tsdb_rejected_notifications") == seen
