"""NGSI-LD errors as ProblemDetails (ETSI GS CIM 009 clauses 5.5.2, 5.5.3).

Every ``TsdbError`` names an NGSI-LD error type (``ld_type``); under
``/ngsi-ld/`` the app's one error handler (``http.errors``) renders it as

    {"type": "https://uri.etsi.org/ngsi-ld/errors/<ld_type>", "title", "status", "detail"}

with the media type ``application/json``: clause 5.5.3 asks for RFC 7807's
members but, so that existing clients keep working, the plain JSON media
type rather than ``application/problem+json``.
"""

from __future__ import annotations

from tsdb_service.core.errors import TsdbError

ERROR_TYPE_BASE = "https://uri.etsi.org/ngsi-ld/errors/"
MEDIA_TYPE = "application/json"
PATH_PREFIX = "/ngsi-ld/"
# The notification endpoint is the broker's, not a client's: it keeps the
# NGSI error shape of /v2/notify (see ingest.http_notify).
_NOT_LD = frozenset({"/ngsi-ld/v1/notify"})

# Clause 5.5.2's short descriptions, as each type's title.
TITLES = {
    "InvalidRequest": "The request associated to the operation is syntactically invalid or includes wrong content",
    "BadRequestData": "The request includes input data which does not meet the requirements of the operation",
    "AlreadyExists": "The referred element already exists",
    "OperationNotSupported": "The operation is not supported",
    "ResourceNotFound": "The referred resource has not been found",
    "InternalError": "There has been an error during the operation execution",
    "TooComplexQuery": "The query associated to the operation is too complex and cannot be resolved",
    "TooManyResults": "The query associated to the operation is producing so many results that it can exhaust "
    "client or server resources; it should be made more restrictive",
    "LdContextNotAvailable": "A remote JSON-LD @context referenced in a request cannot be retrieved, so expansion "
    "or compaction cannot be performed",
    "NoMultiTenantSupport": "The NGSI-LD system does not support multiple tenants",
    "NonexistentTenant": "The addressed tenant does not exist",
    "NotAcceptable": "The media type asked for in the Accept header is not supported",
}


def is_ngsild_path(path: str) -> bool:
    """Does an error on this path answer as NGSI-LD ProblemDetails?"""
    return path.startswith(PATH_PREFIX) and path not in _NOT_LD


def problem(ld_type: str, status: int, detail: str) -> dict[str, object]:
    """A ProblemDetails body."""
    return {
        "type": ERROR_TYPE_BASE + ld_type,
        "title": TITLES.get(ld_type, ld_type),
        "status": status,
        "detail": detail,
    }


def problem_of(exc: TsdbError) -> dict[str, object]:
    return problem(exc.ld_type, exc.status, exc.description)


# Framework-level HTTP errors (no route, wrong method...) → NGSI-LD types.
_HTTP_TYPES = {
    404: "ResourceNotFound",
    405: "OperationNotSupported",
    406: "NotAcceptable",
    409: "AlreadyExists",
    422: "OperationNotSupported",
}


def http_ld_type(status: int) -> str:
    if status >= 500:
        return "InternalError"
    return _HTTP_TYPES.get(status, "InvalidRequest" if status in (400, 411, 413, 414, 415) else "BadRequestData")
