"""The operator routes' part of the OpenAPI description: version, health, index, metrics, backups."""

from __future__ import annotations

from tsdb_service.http.openapi import AUTH, STR, errors, json_body, obj, ok, ref, spec

VERSION = obj(("version",), {"version": STR})


HEALTH = spec(
    ok_={
        200: {
            "description": "Healthy (pass), or serving with a concern (warn: the MQTT broker is away, or the "
            "ingest log set damaged records aside for an operator)",
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


INT = {"type": "integer"}
BACKUP_REPORT = obj(
    ("path", "bytes", "seconds", "databaseId", "ingestLogSeq", "tables", "sampledRows", "mismatchedRows", "verified"),
    {
        "path": STR,
        "bytes": INT,
        "seconds": {"type": "number"},
        "databaseId": STR,
        "ingestLogSeq": INT,
        "tables": {
            "type": "object",
            "additionalProperties": obj(("source", "copy"), {"source": INT, "copy": INT}),
        },
        "sampledRows": INT,
        "mismatchedRows": INT,
        "verified": {"type": "boolean"},
    },
    description="What was copied and checked: rows per table in the store and in the copy, sampled rows compared",
)
_BACKUP_SPEC = spec(
    ok_=ok(ref("BackupReport"), "The backup, written and checked", status=201),
    errors_=(400, *AUTH, 503),
    body=json_body(
        obj((), {"name": {"type": "string", "pattern": "^[A-Za-z0-9][A-Za-z0-9._-]{0,127}$"}}),
        required=False,
    ),
)
BACKUP = {
    **_BACKUP_SPEC,
    "responses": {
        **_BACKUP_SPEC["responses"],
        409: {
            "description": "No backup: backups through the service are off (TSDB_BACKUP_DIR), the file exists, "
            "another backup is running, or the backend has its own tools (PostgreSQL)",
            "content": errors(409)[409]["content"],
        },
    },
}


SCHEMAS: dict[str, dict] = {
    "Health": obj(("status",), {"status": {"enum": ["pass", "warn", "fail"]}, "output": STR}),
    "BackupReport": BACKUP_REPORT,
}
