"""The rejected store keeps what a notification carried, minus credentials:
anyone allowed to list rejected notifications must not collect the broker's
tokens, keys or cookies from them."""

from __future__ import annotations

import orjson

from tsdb_service.core.credentials import redact_headers

SECRETS = {
    "Authorization": "Bearer eyJ.secret.token",
    "X-Auth-Token": "keyrock-secret",
    "Cookie": "session=secret-cookie",
    "X-Api-Key": "secret-api-key-0123456789",
    "Proxy-Authorization": "Basic c2VjcmV0",
}


def test_redact_headers_drops_credentials_keeps_the_rest():
    headers = {**{k.lower(): v for k, v in SECRETS.items()}, "fiware-service": "t", "x-orion-key": "custom-secret"}
    redacted = redact_headers(headers, "X-Orion-Key")
    assert redacted["fiware-service"] == "t"
    assert not any("secret" in v for v in redacted.values())
    assert set(redacted) == set(headers)


def test_rejected_notification_keeps_no_credentials(client_factory, store_url):
    with client_factory(store_url, api_key_header="X-Orion-Key") as client:
        response = client.post(
            "/v2/notify",
            content=b"{broken",
            headers={
                "Content-Type": "application/json",
                "Fiware-Service": "acme",
                "X-Orion-Key": "custom-secret",
                **SECRETS,
            },
        )
        assert response.status_code == 400
        rejected = client.get("/v2/notify/rejected", headers={"Fiware-Service": "acme"}).json()
    assert len(rejected) == 1
    stored = rejected[0]["headers"]
    headers = orjson.loads(stored) if isinstance(stored, str) else stored
    assert headers["fiware-service"] == "acme"
    assert "secret" not in orjson.dumps(headers).decode()
