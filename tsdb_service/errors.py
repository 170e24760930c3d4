"""One error hierarchy, rendered by one handler in the NGSI error shape.

Every failure a client can cause is a ``TsdbError`` with an HTTP status, an
NGSI error name and a description. Anything else escaping a route is a bug
and becomes a 500.
"""

from __future__ import annotations


class TsdbError(Exception):
    status: int = 500
    error: str = "InternalError"

    def __init__(self, description: str, *, error: str | None = None, status: int | None = None):
        super().__init__(description)
        self.description = description
        if error is not None:
            self.error = error
        if status is not None:
            self.status = status

    def body(self) -> dict[str, str]:
        return {"error": self.error, "description": self.description}


class BadRequest(TsdbError):
    status = 400
    error = "BadRequest"


class ParseError(BadRequest):
    """A notification or parameter we cannot understand."""

    error = "ParseError"


class NotFound(TsdbError):
    status = 404
    error = "NotFound"


class Conflict(TsdbError):
    status = 409
    error = "Conflict"


class PayloadTooLarge(TsdbError):
    status = 413
    error = "PayloadTooLarge"


class UnsupportedMediaType(TsdbError):
    status = 415
    error = "UnsupportedMediaType"


class Unprocessable(TsdbError):
    status = 422
    error = "Unprocessable"


class Unavailable(TsdbError):
    """The store is closing or broken; the client may retry."""

    status = 503
    error = "ServiceUnavailable"
