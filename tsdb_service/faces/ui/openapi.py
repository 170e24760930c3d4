"""The explorer's part of the OpenAPI description."""

from __future__ import annotations

from tsdb_service.http.openapi import AUTH, STR, STRS, array, obj, ok, spec

UI_PAGE = spec(ok_=ok({"type": "string"}, "The explorer page", "text/html"), errors_=AUTH)


UI_TENANTS = spec(
    ok_=ok(
        array(
            obj(
                ("tenant", "servicePaths", "types", "entities", "series"),
                {
                    "tenant": STR,
                    "servicePaths": STRS,
                    "types": STRS,
                    "entities": {"type": "integer"},
                    "series": {"type": "integer"},
                },
            )
        )
    ),
    errors_=(*AUTH, 503),
)


UI_USECASES = spec(ok_=ok({"type": "object", "additionalProperties": {"type": "object"}}), errors_=AUTH)
