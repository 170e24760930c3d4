"""The notification endpoints' part of the OpenAPI description."""

from __future__ import annotations

from tsdb_service.http.openapi import (
    ANY,
    AUTH,
    FIWARE_SERVICE,
    NGSILD_TENANT,
    NULLABLE_STR,
    STR,
    STRS,
    TENANT_SCHEMA,
    array,
    header,
    json_body,
    obj,
    ok,
    ref,
    ref_array,
    spec,
)

_SP_NOTIFY = {"type": "string", "pattern": r"^/[^#\s,]*(,\s*/[^#\s,]*)*$"}


NOTIFY_HEADERS = [
    header("Fiware-Service", "Tenant of the entities (letters, digits, _; up to 50).", TENANT_SCHEMA),
    header("Fiware-ServicePath", "Service path of the entities: one, or one per entity (comma-separated).", _SP_NOTIFY),
    header("NGSILD-Tenant", "NGSI-LD tenant (Orion-LD); must agree with Fiware-Service.", TENANT_SCHEMA),
    header(
        "Ngsiv2-AttrsFormat",
        "Orion's notification format; without it the body's shape decides.",
        {"enum": ["normalized", "keyValues", "values", "simplifiedNormalized", "simplifiedKeyValues", "legacy"]},
    ),
    header(
        "Ngsild-Attribute-Format",
        "Orion-LD's attribute format.",
        {"enum": ["Normalized", "Concise", "Simplified", "KeyValues"]},
    ),
    header(
        "Fiware-TimeIndex-Attribute",
        "Attribute (or metadata) whose value is the time index.",
        {"type": "string", "maxLength": 256},
    ),
]


_NOTIFY_EXAMPLES = {
    "ngsiv2": {
        "subscriptionId": "5f1a",
        "data": [
            {
                "id": "urn:ngsi-ld:Room:1",
                "type": "Room",
                "temperature": {"type": "Number", "value": 21.5},
                "TimeInstant": {"type": "DateTime", "value": "2024-05-01T10:00:00Z"},
            }
        ],
    },
    "ngsi-ld": {
        "id": "urn:ngsi-ld:Notification:1",
        "type": "Notification",
        "subscriptionId": "urn:sub:1",
        "notifiedAt": "2024-05-01T10:00:00Z",
        "data": [
            {
                "id": "urn:ngsi-ld:Room:2",
                "type": "Room",
                "temperature": {"type": "Property", "value": 19, "observedAt": "2024-05-01T10:00:00Z"},
            }
        ],
    },
}


NOTIFY = spec(
    *NOTIFY_HEADERS,
    ok_=ok({"const": "Notification successfully processed"}, "Durable before this answer (DuckDB: in the ingest log)"),
    errors_=(400, *AUTH, 413, 415, 422, 503),
    body=json_body(
        ref("Notification"),
        media_types=("application/json", "application/ld+json", "application/geo+json"),
        examples=_NOTIFY_EXAMPLES,
    ),
)


_NEXT = {
    "Link": {
        "description": 'The next page: <...>; rel="next" (only when more rows follow)',
        "schema": {"type": "string"},
    },
    "X-Next-Offset": {"description": "offset of the next page", "schema": {"type": "integer"}},
}


REJECTED = spec(FIWARE_SERVICE, NGSILD_TENANT, ok_=ok(ref_array("RejectedNotification")), errors_=(400, *AUTH, 503))


REJECTED["responses"][200]["headers"] = _NEXT


LAYOUTS = {"type": "object", "additionalProperties": ref("ValuesLayout"), "description": "subscription id → layout"}


PUT_LAYOUT = spec(
    FIWARE_SERVICE,
    NGSILD_TENANT,
    ok_=ok(ref("ValuesLayout"), "Registered"),
    errors_=(400, *AUTH, 503),
    body=json_body(
        {
            "anyOf": [
                obj(("attrs",), {"attrs": {**STRS, "minItems": 1}, "entityId": STR, "entityType": STR}, extra=True),
                obj(
                    ("notification",),
                    {"notification": {"type": "object"}, "subject": {"type": "object"}},
                    extra=True,
                    description="A whole Orion subscription: notification.attrs and subject.entities are used",
                ),
            ]
        },
        examples={"short": {"attrs": ["id", "type", "temperature"]}},
    ),
)


SCHEMAS: dict[str, dict] = {
    "NotificationV2": obj(
        ("data",),
        {
            "subscriptionId": STR,
            "data": array({"anyOf": [ref("EntityV2"), array(ANY, "a row of Orion's 'values' format")]}),
        },
        extra=True,
        description="NGSIv2 notification (normalized, keyValues or values: Ngsiv2-AttrsFormat)",
    ),
    "EntityV2": obj(
        ("id",),
        {"id": STR, "type": STR},
        extra=True,
        description="An NGSIv2 entity: {name: {type, value, metadata}} or, keyValues, {name: value}",
    ),
    "NotificationLD": obj(
        ("type", "data"),
        {
            "id": STR,
            "type": {"const": "Notification"},
            "subscriptionId": STR,
            "notifiedAt": STR,
            "data": {
                "anyOf": [
                    array(ref("EntityLD")),
                    obj(
                        ("type",),
                        {"type": {"enum": ["FeatureCollection", "Feature"]}},
                        extra=True,
                        description="GeoJSON (application/geo+json)",
                    ),
                ]
            },
        },
        extra=True,
        description="NGSI-LD notification (normalized, concise or simplified: Ngsild-Attribute-Format)",
    ),
    "NotificationV1": obj(
        ("contextResponses",),
        {"subscriptionId": STR, "originator": STR, "contextResponses": array({"type": "object"})},
        extra=True,
        description="NGSIv1 notification (Orion 'legacy' format)",
    ),
    "Notification": {
        "anyOf": [ref("NotificationV2"), ref("NotificationLD"), ref("NotificationV1"), ref("EntityV2")],
        "description": "Any notification a broker sends; the bare entity is Orion's simplified "
        "formats. Open: unknown members are ignored or stored as attributes.",
    },
    "ValuesLayout": obj(
        ("attrs", "entityId", "entityType"), {"attrs": STRS, "entityId": NULLABLE_STR, "entityType": NULLABLE_STR}
    ),
    "RejectedNotification": obj(
        (
            "id",
            "tenant",
            "receivedAt",
            "error",
            "description",
            "headers",
            "body",
            "bodyEncoding",
            "bodySize",
            "bodyTruncated",
            "topic",
        ),
        {
            "id": {"type": "integer"},
            "tenant": STR,
            "receivedAt": STR,
            "error": STR,
            "description": STR,
            "headers": {"type": "object", "additionalProperties": STR, "description": "credentials redacted"},
            "body": STR,
            "bodyEncoding": {"enum": ["utf-8", "base64"]},
            "bodySize": {"type": "integer"},
            "bodyTruncated": {"type": "boolean"},
            "topic": {**NULLABLE_STR, "description": "the MQTT topic it came on; null: over HTTP"},
        },
    ),
}
