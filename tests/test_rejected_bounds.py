"""The rejected store is bounded per tenant and pages its answers by size.

Count, bytes and age per tenant (``TSDB_REJECTED_MAX_*``), oldest dropped
first, a tenant's newest rejection always kept, what was dropped counted in
``/metrics``; a listing stops before ``TSDB_REJECTED_PAGE_MAX_BYTES`` (at
least one row) and names the next page in ``Link`` and ``X-Next-Offset``.
"""

from __future__ import annotations

import re
import time

JSON = {"Content-Type": "application/json"}


def reject(client, tenant: str, n: int, size: int = 100) -> None:
    """A notification of about ``size`` bytes that gets 400 (no 'data')."""
    body = b'{"subscriptionId": "' + str(n).encode() + b'", "pad": "' + b"x" * size + b'"}'
    r = client.post("/v2/notify", content=body, headers={**JSON, "Fiware-Service": tenant})
    assert r.status_code == 400, r.text


def kept(client, tenant: str) -> list[str]:
    r = client.get("/v2/notify/rejected", headers={"Fiware-Service": tenant})
    assert r.status_code == 200, r.text
    return [re.search(r'"subscriptionId": "(\d+)"', row["body"]).group(1) for row in r.json()]


def dropped(client) -> dict[str, float]:
    text = client.get("/metrics").text
    return {m[0]: float(m[1]) for m in re.findall(r'^tsdb_rejected_dropped_total\{reason="(\w+)"\} (\S+)$', text, re.M)}


def test_count_per_tenant(client_factory, store_url):
    with client_factory(store_url, rejected_max_per_tenant=3) as client:
        for n in range(5):
            reject(client, "a", n)
        for n in range(2):
            reject(client, "b", n)
        assert kept(client, "a") == ["4", "3", "2"]
        assert kept(client, "b") == ["1", "0"]
        assert dropped(client) == {"age": 0, "bytes": 0, "count": 2}


def test_bytes_per_tenant_keeps_the_newest(client_factory, store_url):
    with client_factory(store_url, rejected_max_bytes_per_tenant=4096) as client:
        for n in range(5):
            reject(client, "a", n, size=1000)
        rows = kept(client, "a")
        assert rows[0] == "4" and 1 <= len(rows) < 5
        reject(client, "a", 9, size=8000)  # alone over the bound: kept, the rest dropped
        assert kept(client, "a") == ["9"]
        assert dropped(client)["bytes"] == 5


def test_age(client_factory, store_url):
    with client_factory(store_url, rejected_max_age_days=0.5 / 86400) as client:
        reject(client, "a", 0)
        reject(client, "b", 1)
        time.sleep(0.6)
        reject(client, "a", 2)
        assert kept(client, "a") == ["2"]
        assert kept(client, "b") == []
        assert dropped(client)["age"] == 2


def pages(client, headers: dict, params: dict) -> list[list[dict]]:
    out, url = [], "/v2/notify/rejected"
    while True:
        r = client.get(url, headers=headers, params=params)
        assert r.status_code == 200, r.text
        out.append(r.json())
        link = r.headers.get("link")
        if link is None:
            assert "x-next-offset" not in r.headers
            return out
        url, params = re.fullmatch(r'<([^>]+)>; rel="next"', link).group(1), None
        assert f"offset={r.headers['x-next-offset']}" in url


def test_pages_by_size(client_factory, store_url):
    with client_factory(store_url, rejected_page_max_bytes=4096) as client:
        for n in range(6):
            reject(client, "a", n, size=1500)
        reject(client, "a", 6, size=9000)  # bigger than a page: a page of its own
        got = pages(client, {"Fiware-Service": "a"}, {"limit": 100})
        assert next(len(p) for p in got) == 1
        assert all(1 <= len(p) <= 2 for p in got)
        flat = [re.search(r'"subscriptionId": "(\d+)"', row["body"]).group(1) for p in got for row in p]
        assert flat == ["6", "5", "4", "3", "2", "1", "0"]
        # By count as before, the next page named too.
        r = client.get("/v2/notify/rejected", headers={"Fiware-Service": "a"}, params={"limit": 1, "offset": 6})
        assert len(r.json()) == 1 and "link" not in r.headers
        r = client.get("/v2/notify/rejected", headers={"Fiware-Service": "a"}, params={"limit": 1, "offset": 5})
        assert r.headers["x-next-offset"] == "6"
        # The operator's listing pages the same way.
        everything = pages(client, {}, {"allTenants": "true"})
        assert sum(len(p) for p in everything) == 7
