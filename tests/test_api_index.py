"""``GET /v2``: QuantumLeap's index of API URLs, listing only URLs we serve."""

from __future__ import annotations


def test_index_lists_quantumleaps_urls_that_exist(client):
    r = client.get("/v2")
    assert r.status_code == 200
    index = r.json()
    assert index == {
        "notify_url": "/v2/notify",
        "subscribe_url": "/v2/subscribe",
        "entities_url": "/v2/entities",
        "attributes_url": "/v2/attrs",
        "op_query_url": "/v2/op/query",
    }
    assert client.get("/v2/").json() == index
    served_by_get = {"/v2/entities", "/v2/attrs"}  # the others are served by POST only
    for url in index.values():
        assert client.get(url).status_code == (200 if url in served_by_get else 405), url


def test_urls_quantumleap_names_but_nobody_serves_are_not_listed(client):
    for url in ("/v2/subscriptions", "/v2/types"):
        assert url not in client.get("/v2").json().values()
        assert client.get(url).status_code == 404
