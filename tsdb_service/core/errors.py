"""One error hierarchy, rendered by one handler in the NGSI error shape.

Every failure a client can cause is a ``TsdbError`` with an HTTP status, an
NGSI error name and a description. Anything else escaping a route is a bug
and becomes a 500.

Under ``/ngsi-ld/`` the same errors are rendered as NGSI-LD ProblemDetails
(RFC 7807, ETSI GS CIM 009 clause 6.3.2): each class also names its NGSI-LD
error type (``ld_type``); the classes at the end are the NGSI-LD types the
generic ones do not already give. ``http.errors`` renders both shapes.
"""

from __future__ import annotations


class TsdbError(Exception):
    status: int = 500
    error: str = "InternalError"
    ld_type: str = "InternalError"  # the NGSI-LD error type (https://uri.etsi.org/ngsi-ld/errors/<ld_type>)

    def __init__(
        self, description: str, *, error: str | None = None, status: int | None = None, ld_type: str | None = None
    ):
        super().__init__(description)
        self.description = description
        if error is not None:
            self.error = error
        if status is not None:
            self.status = status
        if ld_type is not None:
            self.ld_type = ld_type

    def body(self) -> dict[str, str]:
        return {"error": self.error, "description": self.description}


class BadRequest(TsdbError):
    status = 400
    error = "BadRequest"
    ld_type = "BadRequestData"


class ParseError(BadRequest):
    """A notification or parameter we cannot understand."""

    error = "ParseError"


class NotFound(TsdbError):
    status = 404
    error = "NotFound"
    ld_type = "ResourceNotFound"


class AggrNotApplicable(TsdbError):
    """QuantumLeap's answer to sum/avg/min/max on text or boolean values."""

    status = 404
    error = "AggrMethod cannot be applied"

    def __init__(self) -> None:
        super().__init__("AggrMethod cannot be applied on type TEXT and BOOLEAN.")


class Conflict(TsdbError):
    status = 409
    error = "Conflict"
    ld_type = "AlreadyExists"


class PayloadTooLarge(TsdbError):
    status = 413
    error = "PayloadTooLarge"
    ld_type = "InvalidRequest"


class UnsupportedMediaType(TsdbError):
    status = 415
    error = "UnsupportedMediaType"
    ld_type = "InvalidRequest"


class Unprocessable(TsdbError):
    status = 422
    error = "Unprocessable"
    ld_type = "OperationNotSupported"


class NotStorable(Unprocessable):
    """The database refused this write again and again while it takes
    others: the content is at fault (a poison message), not the database.
    Retrying cannot help; a notification is kept in the rejected store."""

    error = "NotStorable"


class Unauthorized(TsdbError):
    """No credential, or one we cannot verify: the client should authenticate."""

    status = 401
    error = "Unauthorized"
    ld_type = "Unauthorized"  # no NGSI-LD type covers authentication (clause 5.5.2)


class MissingCredential(Unauthorized):
    """No credential at all (the challenge then carries no error code)."""


class Forbidden(TsdbError):
    """A verified caller asking for more than it was granted (scope or tenant)."""

    status = 403
    error = "Forbidden"
    ld_type = "Forbidden"


class Unavailable(TsdbError):
    """The store is closing or broken; the client may retry."""

    status = 503
    error = "ServiceUnavailable"


# --- NGSI-LD error types (ETSI GS CIM 009 clause 5.5.2) ----------------------------------------


class InvalidRequest(BadRequest):
    """Syntactically invalid: not JSON, not an object, a malformed parameter."""

    error = "InvalidRequest"
    ld_type = "InvalidRequest"


class BadRequestData(BadRequest):
    """Well-formed, but the data does not meet the operation's requirements."""

    error = "BadRequestData"
    ld_type = "BadRequestData"


class ResourceNotFound(NotFound):
    error = "ResourceNotFound"
    ld_type = "ResourceNotFound"


class AlreadyExists(Conflict):
    error = "AlreadyExists"
    ld_type = "AlreadyExists"


class OperationNotSupported(Unprocessable):
    error = "OperationNotSupported"
    ld_type = "OperationNotSupported"


class TooComplexQuery(TsdbError):
    status = 403
    error = "TooComplexQuery"
    ld_type = "TooComplexQuery"


class TooManyResults(TsdbError):
    status = 403
    error = "TooManyResults"
    ld_type = "TooManyResults"


class NonexistentTenant(NotFound):
    error = "NonexistentTenant"
    ld_type = "NonexistentTenant"


class NotAcceptable(TsdbError):
    status = 406
    error = "NotAcceptable"
    ld_type = "NotAcceptable"


class LdContextNotAvailable(TsdbError):
    status = 503
    error = "LdContextNotAvailable"
    ld_type = "LdContextNotAvailable"


def first_line(exc: BaseException) -> str:
    """A failure in one line of at most 300 characters, for ``/health`` and
    logs: a driver's message without the lines of context it appends."""
    text = str(exc).strip()
    return text.splitlines()[0][:300] if text else type(exc).__name__
