"""The one place errors become HTTP responses, always in the NGSI shape
``{"error": ..., "description": ...}``."""

from __future__ import annotations

import logging

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from starlette.exceptions import HTTPException as StarletteHTTPException

from ..errors import TsdbError
from .responses import JSON

log = logging.getLogger("tsdb_service")

_HTTP_NAMES = {404: "NotFound", 405: "MethodNotAllowed", 413: "PayloadTooLarge", 415: "UnsupportedMediaType"}


def install_error_handlers(app: FastAPI) -> None:
    @app.exception_handler(TsdbError)
    async def tsdb_error(_: Request, exc: TsdbError) -> JSON:
        return JSON(exc.body(), status_code=exc.status)

    @app.exception_handler(RequestValidationError)
    async def validation_error(_: Request, exc: RequestValidationError) -> JSON:
        problems = "; ".join(
            f"{'.'.join(str(p) for p in err.get('loc', ())[1:]) or 'request'}: {err.get('msg')}"
            for err in exc.errors()
        )
        return JSON({"error": "BadRequest", "description": problems or "invalid request"}, status_code=400)

    @app.exception_handler(StarletteHTTPException)
    async def http_error(_: Request, exc: StarletteHTTPException) -> JSON:
        name = _HTTP_NAMES.get(exc.status_code, "BadRequest" if exc.status_code < 500 else "InternalError")
        return JSON({"error": name, "description": str(exc.detail)}, status_code=exc.status_code)

    @app.exception_handler(Exception)
    async def unexpected(_: Request, exc: Exception) -> JSON:
        log.exception("unhandled error", exc_info=exc)
        return JSON(
            {"error": "InternalError", "description": f"unexpected {type(exc).__name__}; this is a bug"},
            status_code=500,
        )
