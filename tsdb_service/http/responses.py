"""Response helpers shared by every route."""

from __future__ import annotations

from collections.abc import Sequence
from datetime import timedelta
from typing import Any

import orjson
from starlette.responses import JSONResponse

from tsdb_service.core.buckets import label

# What a drawn answer says about itself (long windows, docs/long-windows.md):
# the bucket width of its points (``raw``: the samples as stored), and what
# a cap left out, in words. Browsers may read them across origins (CORS).
BUCKET_HEADER = "X-Tsdb-Bucket"
BUCKET_MS_HEADER = "X-Tsdb-Bucket-Ms"
TRUNCATED_HEADER = "X-Tsdb-Truncated"
NOTICE_HEADER = "X-Tsdb-Notice"
EXPOSED_HEADERS = (BUCKET_HEADER, BUCKET_MS_HEADER, TRUNCATED_HEADER, NOTICE_HEADER, "Link")


class JSON(JSONResponse):
    """JSON via orjson: several times faster than the stdlib on big histories.
    A ``JSONResponse`` so that the OpenAPI description types its answers as
    JSON (each route declares the schema), not as strings."""

    media_type = "application/json"

    def render(self, content: Any) -> bytes:
        return orjson.dumps(content, option=orjson.OPT_NON_STR_KEYS | orjson.OPT_SERIALIZE_NUMPY)


def drawn_headers(width: timedelta | None = None, raw: bool = False, notices: Sequence[str] = ()) -> dict[str, str]:
    """The headers of an answer that draws: ``X-Tsdb-Bucket`` (``1h``, or
    ``raw``) with ``X-Tsdb-Bucket-Ms``; and, when a cap left something out,
    ``X-Tsdb-Truncated: true`` with ``X-Tsdb-Notice`` saying what (notices
    joined by `` | ``, in printable ASCII: a header cannot carry more)."""
    headers = {}
    if width is not None:
        headers[BUCKET_HEADER] = label(width)
        headers[BUCKET_MS_HEADER] = str(width // timedelta(milliseconds=1))
    elif raw:
        headers[BUCKET_HEADER] = "raw"
    if notices:
        headers[TRUNCATED_HEADER] = "true"
        text = " | ".join(notices)
        headers[NOTICE_HEADER] = "".join(c if " " <= c <= "~" else "?" for c in text)[:2000]
    return headers
