"""Every rejected notification keeps its body, its size and its tenant.

Orion never sends a notification twice: whatever we refuse must stay
recoverable. Over the body limit (413) the first bytes are kept up to
TSDB_REJECTED_BODY_MAX_BYTES with the full size; a tenant header the API
refuses is stored as received and shown by the operator listing across
tenants; databases from before migration 0002 keep working.
"""

from __future__ import annotations

import orjson
import pytest

from tsdb_service.core.config import Settings

MIB = 1024 * 1024
ORION_DEFAULT_MAX = 8 * MIB  # Orion's -outReqMsgMaxSize default ("8MB")


HEAD = b'{"subscriptionId":"s","data":[{"id":"E","type":"T","blob":{"type":"Text","value":"'
TAIL = b'"}}]}'


def body_of(size: int) -> bytes:
    """A valid notification of exactly ``size`` bytes."""
    return HEAD + b"x" * (size - len(HEAD) - len(TAIL)) + TAIL


def test_defaults_take_what_a_default_orion_sends():
    settings = Settings()
    assert settings.max_body_bytes > ORION_DEFAULT_MAX
    assert settings.rejected_body_max_bytes >= settings.max_body_bytes


def test_a_notification_of_orions_default_maximum_is_stored(client):
    raw = body_of(ORION_DEFAULT_MAX)
    response = client.post("/v2/notify", content=raw, headers={"Content-Type": "application/json"})
    assert response.status_code == 200, response.text[:200]
    [value] = client.get("/v2/entities/E/attrs/blob/value").json()["values"]
    assert len(value) == ORION_DEFAULT_MAX - len(HEAD) - len(TAIL)


@pytest.fixture
def small(client_factory, store_url):
    with client_factory(store_url, max_body_bytes=1024, rejected_body_max_bytes=3000) as client:
        yield client


def listing(client, tenant="big"):
    return client.get("/v2/notify/rejected", headers={"Fiware-Service": tenant}).json()


def test_over_the_limit_under_the_cap_is_kept_whole(small):
    raw = body_of(2000)
    response = small.post(
        "/v2/notify", content=raw, headers={"Content-Type": "application/json", "Fiware-Service": "big"}
    )
    assert response.status_code == 413
    assert "2000 bytes exceeds the 1024-byte limit" in response.json()["description"]
    [kept] = listing(small)
    assert (kept["body"].encode(), kept["bodySize"], kept["bodyTruncated"]) == (raw, 2000, False)
    assert kept["error"] == "PayloadTooLarge"


def test_over_the_cap_keeps_the_first_bytes_and_the_size(small):
    raw = body_of(50_000)
    assert (
        small.post(
            "/v2/notify", content=raw, headers={"Content-Type": "application/json", "Fiware-Service": "big"}
        ).status_code
        == 413
    )
    [kept] = listing(small)
    assert (kept["body"].encode(), kept["bodySize"], kept["bodyTruncated"]) == (raw[:3000], 50_000, True)


def test_a_chunked_body_is_counted(small):
    raw = body_of(20_000)
    chunks = (raw[i : i + 1000] for i in range(0, len(raw), 1000))
    response = small.post(
        "/v2/notify", content=chunks, headers={"Content-Type": "application/json", "Fiware-Service": "big"}
    )
    assert response.status_code == 413
    [kept] = listing(small)
    assert (kept["body"].encode(), kept["bodySize"], kept["bodyTruncated"]) == (raw[:3000], 20_000, True)


def test_a_415_over_the_limit_is_kept_too(small):
    raw = b"x" * 5000
    response = small.post("/v2/notify", content=raw, headers={"Content-Type": "text/plain", "Fiware-Service": "big"})
    assert response.status_code == 413  # too big is reported first; the body is kept either way
    [kept] = listing(small)
    assert (kept["bodySize"], kept["bodyTruncated"], len(kept["body"])) == (5000, True, 3000)


def test_a_parse_error_keeps_the_body(client):
    raw = b'{"subscriptionId": "s", "data": [{"id": 5}]}'
    response = client.post(
        "/v2/notify", content=raw, headers={"Content-Type": "application/json", "Fiware-Service": "big"}
    )
    assert response.status_code == 400
    [kept] = listing(client)
    assert (kept["body"].encode(), kept["bodySize"], kept["bodyTruncated"]) == (raw, len(raw), False)
    assert kept["tenant"] == "big"


def test_operator_listing_across_tenants(client):
    bad_tenant = "Not A Tenant!"
    for tenant in ("alpha", "beta", bad_tenant):
        response = client.post(
            "/v2/notify", content=b"{broken", headers={"Content-Type": "application/json", "Fiware-Service": tenant}
        )
        assert response.status_code == 400
    assert [r["tenant"] for r in listing(client, "alpha")] == ["alpha"]
    # The refused tenant cannot be named on the per-tenant listing...
    assert client.get("/v2/notify/rejected", headers={"Fiware-Service": bad_tenant}).status_code == 400
    # ...but the operator listing shows it, stored as received, newest first.
    every = client.get(
        "/v2/notify/rejected", params={"allTenants": "true"}, headers={"Fiware-Service": bad_tenant}
    ).json()
    assert [r["tenant"] for r in every] == [bad_tenant, "beta", "alpha"]
    assert every[0]["headers"]["fiware-service"] == bad_tenant and every[0]["body"] == "{broken"
    paged = client.get("/v2/notify/rejected", params={"allTenants": "true", "limit": 1, "offset": 1}).json()
    assert [r["tenant"] for r in paged] == ["beta"]


def test_a_database_from_before_0002_keeps_working(client_factory, store_url, backend):
    with client_factory(store_url) as client:
        client.post("/v2/notify", content=b"{old", headers={"Content-Type": "application/json"})
    _downgrade_to_0001(store_url, backend)
    with client_factory(store_url) as client:
        [old] = client.get("/v2/notify/rejected").json()
        assert (old["body"], old["bodySize"], old["bodyTruncated"]) == ("{old", 4, False)
        client.post("/v2/notify", content=b"{new", headers={"Content-Type": "application/json"})
        assert [r["body"] for r in client.get("/v2/notify/rejected").json()] == ["{new", "{old"]


def _downgrade_to_0001(url: str, backend: str) -> None:
    """Make the store look like one written before migration 0002."""
    statements = [
        "ALTER TABLE rejected_notifications DROP COLUMN body_size",
        "ALTER TABLE rejected_notifications DROP COLUMN body_truncated",
        "DELETE FROM schema_migrations WHERE version = 2",
    ]
    if backend == "postgresql":
        import psycopg

        with psycopg.connect(url, autocommit=True) as conn:
            for sql in statements:
                conn.execute(sql)
        return
    import duckdb

    con = duckdb.connect(url)
    try:
        for sql in statements:
            con.execute(sql)
    finally:
        con.close()


def test_rejected_rows_survive_copy_with_size(client_factory, store_url_factory):
    # The size and truncation flag travel with `tsdb-service copy`.
    from tsdb_service.commands.copy import copy_history
    from tsdb_service.storage import open_store

    source_url, target_url = store_url_factory("copy_source"), store_url_factory("copy_target")
    with client_factory(source_url, max_body_bytes=1024, rejected_body_max_bytes=3000) as client:
        assert (
            client.post(
                "/v2/notify",
                content=body_of(50_000),
                headers={"Content-Type": "application/json", "Fiware-Service": "big"},
            ).status_code
            == 413
        )
    source, target = open_store(Settings(db=source_url)), open_store(Settings(db=target_url))
    try:
        copy_history(source, target, source_id=source_url)
        [row] = target.rejected("big", 10, 0)
        assert (row["bodySize"], row["bodyTruncated"], len(row["body"])) == (50_000, True, 3000)
    finally:
        source.close()
        target.close()


def test_rejected_listing_is_json_for_binary_bodies(client):
    raw = b"\xff\xfe{"
    assert (
        client.post(
            "/v2/notify", content=raw, headers={"Content-Type": "application/json", "Fiware-Service": "big"}
        ).status_code
        == 400
    )
    [kept] = listing(client)
    assert kept["bodyEncoding"] == "base64" and kept["bodySize"] == 3
    assert orjson.loads(orjson.dumps(kept)) == kept
