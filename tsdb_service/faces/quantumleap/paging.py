"""What a server-side limit left out of a QuantumLeap answer, said in headers.

QuantumLeap pages history with ``limit`` and ``offset`` (and ``lastN``):
what the client asks is its own page and needs no word. The service's limit
(``TSDB_DEFAULT_LIMIT``, 10,000 rows) applies when the client gave none, or
a larger one; an answer that reached it may have left rows out, so it
carries ``X-Tsdb-Truncated: true``, ``X-Tsdb-Notice`` and a ``Link`` to the
next page (``rel="next"``: the same request with ``offset`` moved on).
The rows are QuantumLeap's, unchanged.
"""

from __future__ import annotations

from collections.abc import Iterable
from urllib.parse import urlencode

from fastapi import Request

from tsdb_service.http.responses import drawn_headers


def limit_headers(request: Request, limit: int, offset: int, rows_per_group: Iterable[int]) -> dict[str, str]:
    """Headers when the service's ``limit`` (not the client's) was reached by
    a group of rows it applies to (a type's rows: QuantumLeap pages each
    entity type on its own)."""
    params = request.query_params
    if not _imposed(params.get("limit"), limit) or not any(n >= limit for n in rows_per_group):
        return {}
    last_n = _number(params.get("lastN"))
    if last_n is not None and last_n <= limit:
        return {}
    notice = (
        f"the answer stops at the service's limit of {limit} rows (TSDB_DEFAULT_LIMIT): there may be more; "
        f"ask the next page with offset={offset + limit}"
    )
    headers = drawn_headers(notices=[notice])
    following = urlencode([*((k, v) for k, v in params.multi_items() if k != "offset"), ("offset", offset + limit)])
    headers["Link"] = f'<{request.url.path}?{following}>; rel="next"'
    return headers


def _imposed(asked: str | None, limit: int) -> bool:
    """The limit applied is the service's: none was asked, or a larger one."""
    number = _number(asked)
    return number is None or number > limit


def _number(text: str | None) -> int | None:
    try:
        return None if text is None or not text.strip() else int(text)
    except ValueError:
        return None
