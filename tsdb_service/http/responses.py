"""Response helpers shared by every route."""

from __future__ import annotations

from typing import Any

import orjson
from starlette.responses import JSONResponse


class JSON(JSONResponse):
    """JSON via orjson: several times faster than the stdlib on big histories.
    A ``JSONResponse`` so that the OpenAPI description types its answers as
    JSON (each route declares the schema), not as strings."""

    media_type = "application/json"

    def render(self, content: Any) -> bytes:
        return orjson.dumps(content, option=orjson.OPT_NON_STR_KEYS | orjson.OPT_SERIALIZE_NUMPY)
