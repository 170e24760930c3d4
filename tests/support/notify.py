"""POST a notification through a test client and insist it was stored."""

from __future__ import annotations


def post_notification(client, body: dict, headers: dict | None = None):
    """POST one notification; fail the test unless it was stored."""
    response = client.post("/v2/notify", json=body, headers={"Content-Type": "application/json", **(headers or {})})
    assert response.status_code == 200, response.text
    return response
