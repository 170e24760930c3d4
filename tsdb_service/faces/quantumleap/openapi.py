"""The QuantumLeap API's part of the OpenAPI description: its parameters, answers and schemas."""

from __future__ import annotations

from tsdb_service.http.openapi import (
    ANY,
    ATTRS,
    AUTH,
    FIWARE_SERVICE,
    FROM_DATE,
    GEO,
    ID,
    ID_PATTERN,
    LIMIT,
    NGSILD_TENANT,
    NULLABLE_STR,
    OFFSET,
    POSITIVE,
    READ_ERRORS,
    SERVICE_PATH_QUERY,
    STR,
    STRS,
    TENANCY,
    TIME,
    TO_DATE,
    TYPE,
    array,
    json_body,
    obj,
    ok,
    query,
    ref,
    ref_array,
    spec,
)

_INDEX = array(STR, "time indices, UTC ISO 8601 with milliseconds (2024-05-01T10:00:00.123+00:00)")


_VALUES = array(ANY, "values, parallel to index")


_EMPTY = {"type": "array", "maxItems": 0, "description": "nothing matched"}


_ONE_HEAD = [{"required": ["id"]}, {"required": ["ids"]}]  # ids: aggrScope=global


_ATTR_VALUES = obj(("attrName", "values"), {"attrName": STR, "values": _VALUES})


_TYPE_ENTITY = obj(
    ("index", "attributes"), {"id": STR, "ids": STRS, "index": _INDEX, "attributes": array(_ATTR_VALUES)}
)


_TYPE_ENTITY["anyOf"] = _ONE_HEAD


_TYPE_ATTR_ENTITY = obj(("index", "values"), {"id": STR, "ids": STRS, "index": _INDEX, "values": _VALUES})


_TYPE_ATTR_ENTITY["anyOf"] = _ONE_HEAD


_ATTR_TYPE = {
    **obj(("entities",), {"type": STR, "types": STRS, "entities": array(ref("TypeAttrEntity"))}),
    "anyOf": [{"required": ["type"]}, {"required": ["types"]}],
}


_ATTR_TYPES = obj(("attrName", "types"), {"attrName": STR, "types": array(ref("AttrTypeGroup"))})


HISTORY_ERRORS = (400, *AUTH, 404, 409, 422, 503)


def maybe_empty(name: str) -> dict:
    return {"anyOf": [ref(name), _EMPTY]}


HISTORY = [
    *TENANCY,
    ATTRS,
    FROM_DATE,
    TO_DATE,
    query("lastN", "Only the newest N samples per entity.", POSITIVE),
    LIMIT,
    OFFSET,
    query("aggrMethod", "Aggregate per entity (case-insensitive).", {"enum": ["count", "sum", "avg", "min", "max"]}),
    query(
        "aggrPeriod",
        "Aggregation bucket; needs aggrMethod.",
        {"enum": ["year", "month", "day", "hour", "minute", "second"]},
    ),
    query(
        "aggrScope",
        "entity: one aggregate per entity; global: one across every matched entity.",
        {"enum": ["entity", "global"]},
    ),
    query("options", "QuantumLeap's options: not supported, any value is refused with 400."),
    *GEO,
]


ENTITY_HISTORY = [TYPE, *HISTORY]  # /v2/entities/{id}...: type disambiguates the id


TYPE_HISTORY = [ID, ID_PATTERN, *HISTORY]


ANY_HISTORY = [ID, TYPE, ID_PATTERN, *HISTORY]


ENTITY_LIST = [*TENANCY, ID, TYPE, ID_PATTERN, FROM_DATE, TO_DATE, LIMIT, OFFSET, *GEO]


DELETE = [
    *TENANCY,
    FROM_DATE,
    TO_DATE,
    query(
        "dropTable",
        "Accepted for QuantumLeap compatibility (true or false); history is deleted either way.",
        {"enum": ["true", "false"]},
    ),
]


DELETE_ENTITY = [TYPE, *DELETE]


SUBSCRIBE = [
    FIWARE_SERVICE,
    SERVICE_PATH_QUERY,
    query(
        "orionUrl",
        "The broker's API base, e.g. http://orion:1026/v2.",
        {"type": "string", "format": "uri"},
        required=True,
    ),
    query(
        "quantumleapUrl",
        "Where the broker reaches this service, e.g. http://tsdb:8668/v2 (it notifies {quantumleapUrl}/notify).",
        {"type": "string", "format": "uri"},
        required=True,
    ),
    query("entityType", "Entity type to follow.", {"type": "string", "maxLength": 256}),
    query("entityId", "Entity id to follow (else idPattern).", {"type": "string", "maxLength": 256}),
    query("idPattern", "Entity id pattern to follow (default .*).", {"type": "string", "maxLength": 256}),
    query("attributes", "Attributes observed and notified, comma-separated."),
    query("observedAttributes", "Attributes whose change notifies, comma-separated."),
    query("notifiedAttributes", "Attributes notified, comma-separated."),
    query(
        "timeIndexAttribute",
        "Attribute carrying the time index (sent as Fiware-TimeIndex-Attribute).",
        {"type": "string", "maxLength": 256},
    ),
    query(
        "throttling",
        "Minimum seconds between notifications (default 1).",
        {"type": "integer", "minimum": 0, "maximum": 999_999_999},
    ),
]


OP_QUERY = spec(
    FIWARE_SERVICE,
    NGSILD_TENANT,
    SERVICE_PATH_QUERY,
    query(
        "asOf",
        "Our extension: the entities as they were at this instant (ISO 8601; naive means UTC), each attribute at "
        "its latest value at or before it, with that value's time as its dateModified metadata.",
        TIME,
    ),
    ok_=ok(ref_array("LastValueEntity")),
    errors_=READ_ERRORS,
    body=json_body(
        obj(
            ("entities",),
            {
                "entities": {
                    **array(
                        {
                            **obj((), {"id": STR, "idPattern": STR, "type": STR}, extra=True),
                            "oneOf": [{"required": ["id"]}, {"required": ["idPattern"]}],
                        }
                    ),
                    "minItems": 1,
                },
                "attrs": array({"type": "string", "minLength": 1}, "attribute names or value paths"),
            },
            extra=True,
            description="Orion's query form; 'expression' and 'metadata' are refused (NotSupported)",
        ),
        examples={"one": {"entities": [{"id": "urn:ngsi-ld:Room:1", "type": "Room"}]}},
    ),
)


SUBSCRIBED = obj(
    ("subscriptionId", "location", "subscription"),
    {"subscriptionId": NULLABLE_STR, "location": NULLABLE_STR, "subscription": {"type": "object"}},
)


SUBSCRIBE_SPEC = spec(*SUBSCRIBE, ok_=ok(SUBSCRIBED, "Created at the broker", status=201), errors_=(400, *AUTH, 502))


SUBSCRIBE_SPEC["responses"]["4XX"] = {
    "description": "The broker's own 4xx, passed on",
    "content": {"application/json": {"schema": ref("NgsiError")}},
}


SCHEMAS: dict[str, dict] = {
    "EntityAttrHistory": obj(
        ("id", "type", "attrName", "index", "values"),
        {"id": STR, "type": STR, "attrName": STR, "index": _INDEX, "values": _VALUES},
    ),
    "EntityAttrValues": obj(("index", "values"), {"index": _INDEX, "values": _VALUES}),
    "EntityHistory": obj(
        ("id", "type", "index", "attributes"),
        {"id": STR, "type": STR, "index": _INDEX, "attributes": array(_ATTR_VALUES)},
    ),
    "EntityValues": obj(("index", "attributes"), {"index": _INDEX, "attributes": array(_ATTR_VALUES)}),
    "TypeEntity": _TYPE_ENTITY,
    "TypeAttrEntity": _TYPE_ATTR_ENTITY,
    "TypeHistory": obj(("type", "entities"), {"type": STR, "entities": array(ref("TypeEntity"))}),
    "TypeValues": obj(("values",), {"values": array(ref("TypeEntity"))}),
    "TypeAttrHistory": obj(
        ("type", "attrName", "entities"), {"type": STR, "attrName": STR, "entities": array(ref("TypeAttrEntity"))}
    ),
    "TypeAttrValues": obj(("values",), {"values": array(ref("TypeAttrEntity"))}),
    "AttrTypeGroup": _ATTR_TYPE,
    "AttrHistory": obj(("attrName", "types"), {"attrName": STR, "types": array(ref("AttrTypeGroup"))}),
    "AttrValues": obj(("values",), {"values": array(ref("AttrTypeGroup"))}),
    "AttrsHistory": obj(("attrs",), {"attrs": array(_ATTR_TYPES)}),
    "AttrsValues": obj(("values",), {"values": array(_ATTR_TYPES)}),
    "EntityListItem": obj(("id", "type", "index"), {"id": STR, "type": STR, "index": STR}),
    "LastValueEntity": obj(
        ("id", "type", "dateModified"),
        {"id": STR, "type": STR},
        extra=obj(
            ("type", "value"),
            {
                "type": STR,
                "value": ANY,
                "metadata": obj(
                    ("dateModified",),
                    {"dateModified": obj(("type", "value"), {"type": STR, "value": STR})},
                    description="with asOf: when the attribute took the value it had then",
                ),
            },
        ),
        description="An entity at its latest values (with asOf: at its values then), NGSIv2 normalized form",
    ),
}

HINT = {
    "X-Tsdb-Hint": {
        "description": "On an empty answer whose tenant holds no data: the tenants that do "
        "(the body stays QuantumLeap's [])",
        "schema": {"type": "string"},
    }
}
