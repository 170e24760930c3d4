"""Listing what a broker holds, page by page: its subscriptions (Orion,
Orion-LD) and its context source registrations (NGSI-LD).

``list_all`` follows the broker's paging (``limit``/``offset``), stopping
at the count it reports (Orion's ``Fiware-Total-Count``, NGSI-LD's
``NGSILD-Results-Count``) or, without one, at a short page; it tells apart
"the broker has none" (``[]``) from "the broker could not tell" (None and
why): a caller that would create what it could not find must not create
it on a broker that could not list.
"""

from __future__ import annotations

from collections.abc import Mapping

import httpx
import orjson

PAGE = 1000  # Orion pages at most 1000; NGSI-LD brokers cap limit as they like
MAX_PAGES = 100


def list_all(
    url: str,
    params: Mapping[str, str | int],
    headers: Mapping[str, str],
    what: str,
    timeout: float = 10.0,
    page_size: int = PAGE,
) -> tuple[list[dict] | None, str]:
    """Every JSON object the listing at ``url`` answers (``params`` on each
    request, ``limit``/``offset`` added): ``(items, "")``, or ``(None,
    why)``. ``what`` names the items in the message."""
    found: list[dict] = []
    for _ in range(MAX_PAGES):
        paged: dict[str, str | int] = {**params, "limit": page_size, "offset": len(found)}
        try:
            response = httpx.get(url, params=paged, headers=dict(headers), timeout=timeout)
        except httpx.HTTPError as exc:
            return None, f"could not reach {url}: {type(exc).__name__}: {exc}"
        if response.status_code != 200:
            answer = f"{response.status_code} {response.reason_phrase}: {' '.join(response.text.split())[:300]}"
            return None, f"listing {url} answered {answer}"
        try:
            page = orjson.loads(response.content)
        except orjson.JSONDecodeError:
            page = None
        if not isinstance(page, list):
            return None, f"listing {url} did not answer a JSON array"
        found.extend(item for item in page if isinstance(item, dict))
        total = response.headers.get("fiware-total-count", response.headers.get("ngsild-results-count", ""))
        more = len(found) < int(total) if total.isdigit() else len(page) >= page_size
        if not page or not more:
            return found, ""
    return None, f"listing {url}: more than {MAX_PAGES * page_size} {what}"
