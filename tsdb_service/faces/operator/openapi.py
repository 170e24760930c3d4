"""The operator routes' part of the OpenAPI description: version, health, index, metrics."""

from __future__ import annotations

from tsdb_service.http.openapi import AUTH, STR, obj, ok, ref, spec

VERSION = obj(("version",), {"version": STR})


HEALTH = spec(
    ok_={
        200: {
            "description": "Healthy (pass), or serving with a concern (warn: the MQTT broker is away)",
            "content": {"application/health+json": {"schema": ref("Health")}},
        },
        503: {
            "description": "Failing: restart or fix the store",
            "content": {"application/health+json": {"schema": ref("Health")}},
        },
    },
    errors_=(),
)


API_INDEX = {"type": "object", "additionalProperties": STR}


METRICS = spec(ok_=ok({"type": "string"}, "Prometheus text exposition format", "text/plain"), errors_=AUTH)


SCHEMAS: dict[str, dict] = {
    "Health": obj(("status",), {"status": {"enum": ["pass", "warn", "fail"]}, "output": STR}),
}
