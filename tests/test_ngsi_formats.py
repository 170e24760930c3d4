"""Every notification format, tenancy, service paths, names and malformed input."""

from __future__ import annotations

import json
import random
from datetime import UTC, datetime

import orjson
import pytest

from tsdb_service.core.errors import ParseError
from tsdb_service.core.model import Kind
from tsdb_service.parse import ValuesLayout, parse_notification

RECEIVED = datetime(2030, 1, 1, tzinfo=UTC)


def parse(body, headers=None, **kwargs):
    raw = body if isinstance(body, (bytes, str)) else orjson.dumps(body)
    return parse_notification(raw, headers or {}, received_at=RECEIVED, **kwargs)


def v2(*entities, fmt="normalized", headers=None, **kwargs):
    hdrs = {"Ngsiv2-AttrsFormat": fmt, **(headers or {})} if fmt else dict(headers or {})
    return parse({"subscriptionId": "sub1", "data": list(entities)}, hdrs, **kwargs)


def ld(*entities, headers=None):
    body = {
        "id": "urn:ngsi-ld:Notification:1",
        "type": "Notification",
        "subscriptionId": "urn:ngsi-ld:Subscription:1",
        "notifiedAt": "2024-05-01T10:00:00.000Z",
        "data": list(entities),
    }
    return parse(body, headers)


def attrs(entity_sample):
    return {a.name: a for a in entity_sample.attrs}


# --- NGSIv2 ----------------------------------------------------------------------


def test_normalized():
    [e] = v2(
        {
            "id": "Room1",
            "type": "Room",
            "temperature": {"type": "Number", "value": 23.5, "metadata": {"unit": {"type": "Text", "value": "C"}}},
            "pressure": {"type": "Integer", "value": 720, "metadata": {}},
            "on": {"type": "Boolean", "value": True},
            "name": {"type": "Text", "value": "kitchen"},
        }
    )
    assert (e.entity_id, e.entity_type, e.tenant, e.service_path) == ("Room1", "Room", "", "/")
    a = attrs(e)
    assert list(a) == ["temperature", "pressure", "on", "name"]
    assert (a["temperature"].kind, a["temperature"].num) == (Kind.NUMBER, 23.5)
    assert json.loads(a["temperature"].md) == {"unit": {"type": "Text", "value": "C"}}
    assert a["pressure"].md is None
    assert (a["pressure"].kind, a["on"].kind, a["name"].txt) == (Kind.INTEGER, Kind.BOOLEAN, "kitchen")


def test_normalized_is_lenient_with_bare_values_and_missing_types():
    [e] = v2(
        {
            "id": "R",
            "type": "T",
            "bare": 5,
            "untyped": {"value": "2024-05-01T00:00:00Z"},
            "geo": {"type": "Point", "coordinates": [1, 2]},
        }
    )
    a = attrs(e)
    assert (a["bare"].kind, a["bare"].num) == (Kind.INTEGER, 5.0)
    assert (a["untyped"].kind, a["untyped"].ngsi_type) == (Kind.DATETIME, "DateTime")
    assert a["geo"].kind is Kind.STRUCTURED  # a keyValues-style object, not an attribute


def test_key_values():
    [e] = v2(
        {
            "id": "R",
            "type": "T",
            "t": 21.5,
            "n": 3,
            "s": "x",
            "b": False,
            "o": {"a": 1},
            "location": {"type": "Point", "coordinates": [2.1, 41.3]},
            "z": None,
        },
        fmt="keyValues",
    )
    kinds = {n: a.kind for n, a in attrs(e).items()}
    assert kinds == {
        "t": Kind.NUMBER,
        "n": Kind.INTEGER,
        "s": Kind.TEXT,
        "b": Kind.BOOLEAN,
        "o": Kind.STRUCTURED,
        "location": Kind.GEO,
        "z": Kind.NULL,
    }
    # in keyValues an object with "value" is a value, not an attribute
    [e] = v2({"id": "R", "type": "T", "o": {"type": "Number", "value": 1}}, fmt="keyValues")
    assert attrs(e)["o"].js == '{"type":"Number","value":1}'


def test_simplified_normalized():
    body = {"id": "R", "type": "T", "t": {"type": "Number", "value": 1.5}}
    [e] = parse(body, {"Ngsiv2-AttrsFormat": "simplifiedNormalized", "Fiware-ServicePath": "/x"})
    assert (e.entity_id, e.service_path, attrs(e)["t"].num) == ("R", "/x", 1.5)


def test_simplified_key_values():
    body = {"id": "R", "type": "T", "t": 1.5, "o": {"type": "Number", "value": 1}}
    [e] = parse(body, {"Ngsiv2-AttrsFormat": "simplifiedKeyValues"})
    a = attrs(e)
    assert (a["t"].kind, a["o"].kind) == (Kind.NUMBER, Kind.STRUCTURED)


def test_header_name_and_value_case_insensitive():
    [e] = parse(
        {"subscriptionId": "s", "data": [{"id": "R", "t": {"type": "Number", "value": 1}}]},
        {"NGSIV2-ATTRSFORMAT": "Normalized"},
    )
    assert attrs(e)["t"].kind is Kind.NUMBER


def test_multiple_entities_in_order():
    out = v2({"id": "A", "type": "T"}, {"id": "B", "type": "U"}, {"id": "C", "type": "T"})
    assert [(e.entity_id, e.entity_type) for e in out] == [("A", "T"), ("B", "U"), ("C", "T")]


def test_empty_data_is_no_entities():
    assert v2() == []


def test_missing_type_is_thing():
    [e] = v2({"id": "R", "t": {"type": "Number", "value": 1}})
    assert e.entity_type == "Thing"


@pytest.mark.parametrize(
    "entity", [{"type": "T"}, {"id": "", "type": "T"}, {"id": 5, "type": "T"}, {"id": None}, {"id": ["a"]}]
)
def test_entity_id_required(entity):
    with pytest.raises(ParseError, match="entity id"):
        v2(entity)


@pytest.mark.parametrize("entity_type", [5, {"a": 1}, True, [3]])
def test_entity_type_must_be_string(entity_type):
    with pytest.raises(ParseError, match="entity type"):
        v2({"id": "R", "type": entity_type})


def test_names_preserved_exactly():
    # Entity ids and types keep any text; attribute names keep everything the
    # name rule allows (names with quotes, white space or over 256 characters
    # are refused: see test_ingest_names.py).
    weird = [
        "Temp'; DROP TABLE entities;--",
        'say "hi"',
        "Ünïcødé 温度 🌡",
        "x" * 256,
        "MiXeD",
        "a.b$c",
        "https://example.org/ns#speed",
        "Ünïcødé_温度_🌡",
        "DROP%20TABLE--",
    ]
    entity = {"id": weird[0], "type": weird[1]}
    entity.update({name: {"type": "Number", "value": 1} for name in weird[3:]})
    [e] = v2(entity, headers={"Fiware-ServicePath": "/Ünïcødé"})
    assert (e.entity_id, e.entity_type, e.service_path) == (weird[0], weird[1], "/Ünïcødé")
    assert [a.name for a in e.attrs] == weird[3:]


# --- values ----------------------------------------------------------------------


def values_body(*rows, subscription="sub1"):
    return {"subscriptionId": subscription, "data": list(rows)}


def test_values_with_id_and_type_columns():
    calls = []

    def lookup(tenant, subscription):
        calls.append((tenant, subscription))
        return ValuesLayout(attrs=("id", "type", "temperature", "on"))

    out = parse(
        values_body(["R1", "Room", 21.5, True], ["R2", "Room", None, False]),
        {"Ngsiv2-AttrsFormat": "values", "Fiware-Service": "Acme"},
        values_layout=lookup,
    )
    assert calls == [("acme", "sub1")]
    assert [(e.entity_id, e.entity_type, e.tenant) for e in out] == [("R1", "Room", "acme"), ("R2", "Room", "acme")]
    assert [a.name for a in out[0].attrs] == ["temperature", "on"]
    assert (out[0].attrs[0].kind, out[1].attrs[0].kind) == (Kind.NUMBER, Kind.NULL)


def test_values_with_fixed_entity():
    layout = ValuesLayout(attrs=("temperature", "TimeInstant"), entity_id="R1", entity_type="Room")
    [e] = parse(
        values_body([20, "2024-05-01T10:00:00Z"]), {"Ngsiv2-AttrsFormat": "values"}, values_layout=lambda t, s: layout
    )
    assert (e.entity_id, e.entity_type) == ("R1", "Room")
    assert e.time_index == datetime(2024, 5, 1, 10, tzinfo=UTC)


def test_values_fixed_entity_without_type_is_thing():
    layout = ValuesLayout(attrs=("t",), entity_id="R1")
    [e] = parse(values_body([1]), {"Ngsiv2-AttrsFormat": "values"}, values_layout=lambda t, s: layout)
    assert e.entity_type == "Thing"


def test_values_detected_without_header():
    layout = ValuesLayout(attrs=("id", "t"))
    [e] = parse(values_body(["R1", 1]), values_layout=lambda t, s: layout)
    assert (e.entity_id, e.entity_type) == ("R1", "Thing")


@pytest.mark.parametrize("lookup", [None, lambda t, s: None])
def test_values_without_layout(lookup):
    with pytest.raises(ParseError, match=r"attribute list.*PUT /v2/notify/subscriptions"):
        parse(values_body([1]), {"Ngsiv2-AttrsFormat": "values"}, values_layout=lookup)


@pytest.mark.parametrize(
    "body, layout, message",
    [
        (values_body([1, 2]), ValuesLayout(("id", "t")), "entity id"),
        (values_body(["R", 1, 2]), ValuesLayout(("id", "t")), "3 values but the subscription lists 2"),
        (values_body({"id": "R"}), ValuesLayout(("id",)), "array of values"),
        (values_body(["R"], subscription=None), ValuesLayout(("id",)), "subscriptionId"),
        (values_body([1]), ValuesLayout(("t",)), "neither an 'id' column"),
    ],
)
def test_values_errors(body, layout, message):
    with pytest.raises(ParseError, match=message):
        parse(body, {"Ngsiv2-AttrsFormat": "values"}, values_layout=lambda t, s: layout)


# --- NGSIv1 legacy ---------------------------------------------------------------


def test_legacy_context_responses():
    body = {
        "subscriptionId": "s",
        "originator": "localhost",
        "contextResponses": [
            {
                "contextElement": {
                    "id": "Room1",
                    "type": "Room",
                    "isPattern": "false",
                    "attributes": [
                        {
                            "name": "temperature",
                            "type": "float",
                            "value": "23",
                            "metadatas": [{"name": "TimeInstant", "type": "ISO8601", "value": "2024-05-01T10:00:00Z"}],
                        }
                    ],
                },
                "statusCode": {"code": "200", "reasonPhrase": "OK"},
            }
        ],
    }
    [e] = parse(body, {"Ngsiv2-AttrsFormat": "legacy"})
    [t] = e.attrs
    assert (e.entity_id, t.name, t.kind, t.num) == ("Room1", "temperature", Kind.NUMBER, 23.0)
    assert e.time_index == datetime(2024, 5, 1, 10, tzinfo=UTC)


@pytest.mark.parametrize(
    "responses",
    [
        "x",
        [5],
        [{"contextElement": 5}],
        [{"contextElement": {"id": "R", "attributes": 5}}],
        [{"contextElement": {"id": "R", "attributes": [{"value": 1}]}}],
    ],
)
def test_legacy_errors(responses):
    with pytest.raises(ParseError):
        parse({"contextResponses": responses})


# --- NGSI-LD ---------------------------------------------------------------------


def test_ld_normalized():
    [e] = ld(
        {
            "id": "urn:ngsi-ld:Vehicle:1",
            "type": "https://uri.etsi.org/ngsi-ld/default-context/Vehicle",
            "@context": ["https://uri.etsi.org/ngsi-ld/v1/ngsi-ld-core-context.jsonld"],
            "createdAt": "2024-01-01T00:00:00Z",
            "modifiedAt": "2024-05-01T00:00:00Z",
            "scope": "/a",
            "speed": {
                "type": "Property",
                "value": 80,
                "unitCode": "KMH",
                "observedAt": "2024-05-01T09:00:00Z",
                "accuracy": {"type": "Property", "value": 0.5},
            },
            "location": {"type": "GeoProperty", "value": {"type": "Point", "coordinates": [2.1493, 41.3763]}},
            "owner": {"type": "Relationship", "object": "urn:ngsi-ld:Person:1"},
            "name": {"type": "LanguageProperty", "languageMap": {"en": "car", "es": "coche"}},
        }
    )
    assert (e.entity_id, e.entity_type) == (
        "urn:ngsi-ld:Vehicle:1",
        "https://uri.etsi.org/ngsi-ld/default-context/Vehicle",
    )
    a = attrs(e)
    assert list(a) == ["speed", "location", "owner", "name"]
    assert (a["speed"].kind, a["speed"].num, a["speed"].ngsi_type) == (Kind.INTEGER, 80.0, "Property")
    assert json.loads(a["speed"].md) == {
        "unitCode": "KMH",
        "observedAt": "2024-05-01T09:00:00Z",
        "accuracy": {"type": "Property", "value": 0.5},
    }
    assert (a["location"].kind, a["location"].ngsi_type, a["location"].md) == (Kind.GEO, "GeoProperty", None)
    assert (a["location"].geo.lon, a["location"].geo.lat) == (2.1493, 41.3763)
    assert (a["owner"].kind, a["owner"].txt) == (Kind.RELATIONSHIP, "urn:ngsi-ld:Person:1")
    assert (a["name"].kind, json.loads(a["name"].js)) == (Kind.STRUCTURED, {"en": "car", "es": "coche"})
    assert e.time_index == datetime(2024, 5, 1, 9, tzinfo=UTC)


def test_ld_type_list_uses_first():
    [e] = ld({"id": "urn:x", "type": ["Vehicle", "Thing2"]})
    assert e.entity_type == "Vehicle"


def test_ld_multi_attribute_keeps_every_instance():
    """Each datasetId is its own attribute (``name~datasetId``); the default keeps the name."""
    [e] = ld(
        {
            "id": "urn:x",
            "type": "T",
            "temp": [
                {"type": "Property", "value": 1, "datasetId": "urn:ds:a"},
                {"type": "Property", "value": 2},
            ],
            "hum": [
                {"type": "Property", "value": 10, "datasetId": "urn:ds:a"},
                {"type": "Property", "value": 20, "datasetId": "urn:ds:b"},
            ],
        }
    )
    a = attrs(e)
    assert (a["temp"].num, a["temp"].md, a["temp"].dataset_id) == (2.0, None, None)
    assert (a["temp~urn:ds:a"].num, a["temp~urn:ds:a"].dataset_id) == (1.0, "urn:ds:a")
    assert (a["hum~urn:ds:a"].num, json.loads(a["hum~urn:ds:a"].md)) == (10.0, {"datasetId": "urn:ds:a"})
    assert (a["hum~urn:ds:b"].num, a["hum~urn:ds:b"].dataset_id) == (20.0, "urn:ds:b")
    assert "hum" not in a


def test_ld_concise_and_key_values():
    [e] = ld(
        {
            "id": "urn:x",
            "type": "T",
            "speed": {"value": 80, "observedAt": "2024-05-01T09:00:00Z"},
            "owner": {"object": "urn:p"},
            "location": {"type": "Point", "coordinates": [1, 2]},
            "plain": 5,
            "text": "hi",
            "array": [1, 2],
            "obj": {"a": 1},
        }
    )
    a = attrs(e)
    assert (a["speed"].kind, a["speed"].ngsi_type, json.loads(a["speed"].md)) == (
        Kind.INTEGER,
        "Property",
        {"observedAt": "2024-05-01T09:00:00Z"},
    )
    assert (a["owner"].kind, a["owner"].ngsi_type) == (Kind.RELATIONSHIP, "Relationship")
    assert (a["location"].kind, a["location"].ngsi_type) == (Kind.GEO, "GeoProperty")
    assert (a["plain"].kind, a["text"].kind, a["array"].kind, a["obj"].kind) == (
        Kind.INTEGER,
        Kind.TEXT,
        Kind.STRUCTURED,
        Kind.STRUCTURED,
    )
    assert e.time_index == datetime(2024, 5, 1, 9, tzinfo=UTC)


def test_ld_relationship_with_value_is_accepted():
    [e] = ld({"id": "urn:x", "type": "T", "owner": {"type": "Relationship", "value": "urn:p"}})
    assert attrs(e)["owner"].txt == "urn:p"


def test_ld_envelope_wins_over_v2_header():
    body = {
        "id": "urn:n",
        "type": "Notification",
        "data": [
            {"id": "urn:x", "type": "T", "p": {"type": "Property", "value": 1, "observedAt": "2024-05-01T00:00:00Z"}}
        ],
    }
    [e] = parse(body, {"Ngsiv2-AttrsFormat": "normalized"})
    assert json.loads(e.attrs[0].md) == {"observedAt": "2024-05-01T00:00:00Z"}


def test_ld_entities_detected_without_envelope_type():
    body = {
        "subscriptionId": "s",
        "data": [{"id": "urn:x", "type": "T", "p": {"type": "Property", "value": 1, "unitCode": "CEL"}}],
    }
    [e] = parse(body)
    assert json.loads(e.attrs[0].md) == {"unitCode": "CEL"}


def test_v2_relationship_without_header_stays_v2():
    body = {
        "subscriptionId": "s",
        "data": [{"id": "R", "type": "T", "ref": {"type": "Relationship", "value": "urn:b", "metadata": {}}}],
    }
    [e] = parse(body)
    assert (e.attrs[0].kind, e.attrs[0].txt) == (Kind.RELATIONSHIP, "urn:b")


def test_header_less_single_entity():
    [e] = parse({"id": "R", "type": "T", "t": {"type": "Number", "value": 1}, "k": 2})
    assert [(a.name, a.kind) for a in e.attrs] == [("t", Kind.NUMBER), ("k", Kind.INTEGER)]


# --- tenancy and service paths --------------------------------------------------------


def test_tenant_lower_cased_and_default():
    assert v2({"id": "R"}, headers={"Fiware-Service": "MyTenant_1"})[0].tenant == "mytenant_1"
    assert v2({"id": "R"}, headers={"fiware-service": "t"})[0].tenant == "t"
    assert v2({"id": "R"})[0].tenant == ""
    assert v2({"id": "R"}, headers={"Fiware-Service": ""})[0].tenant == ""


@pytest.mark.parametrize("tenant", ["a" * 51, "my-tenant", "t/x", "tenant name", "tén", "\u212a", "t;DROP"])
def test_invalid_tenant(tenant):
    with pytest.raises(ParseError, match="tenant"):
        v2({"id": "R"}, headers={"Fiware-Service": tenant})


def test_ld_tenant_header():
    assert ld({"id": "urn:x"}, headers={"NGSILD-Tenant": "OpenIoT"})[0].tenant == "openiot"
    assert ld({"id": "urn:x"}, headers={"Fiware-Service": "Other"})[0].tenant == "other"
    assert ld({"id": "urn:x"}, headers={"NGSILD-Tenant": "OpenIoT", "Fiware-Service": "openiot"})[0].tenant == "openiot"
    with pytest.raises(ParseError, match="tenant"):
        ld({"id": "urn:x"}, headers={"NGSILD-Tenant": "bad tenant"})


def test_conflicting_tenant_headers_are_refused_in_every_format():
    # Stored under one, queried under the other: refused instead (see test_tenancy_selectors).
    for parse_as in (v2, ld):
        with pytest.raises(ParseError, match="conflicting tenant selectors"):
            parse_as({"id": "urn:x"}, headers={"NGSILD-Tenant": "ld", "Fiware-Service": "v2"})


@pytest.mark.parametrize(
    "header, expected", [("/", "/"), ("/a", "/a"), ("/a/", "/a"), ("/a/b", "/a/b"), (" /a ", "/a"), ("", "/")]
)
def test_service_path(header, expected):
    assert v2({"id": "R"}, headers={"Fiware-ServicePath": header})[0].service_path == expected


def test_service_path_comma_form_pairs_with_entities():
    out = v2({"id": "A"}, {"id": "B"}, headers={"Fiware-ServicePath": "/a, /b/"})
    assert [e.service_path for e in out] == ["/a", "/b"]


def test_single_service_path_applies_to_all():
    out = v2({"id": "A"}, {"id": "B"}, headers={"Fiware-ServicePath": "/a"})
    assert [e.service_path for e in out] == ["/a", "/a"]


@pytest.mark.parametrize(
    "header, message",
    [
        ("/a,/b,/c", "3 paths for 2"),
        ("a", "start with"),
        ("/a//b", "empty component"),
        ("/a/#", "#"),
        ("/a,", "start with"),
        ("//", "empty component"),
    ],
)
def test_service_path_errors(header, message):
    with pytest.raises(ParseError, match=message):
        v2({"id": "A"}, {"id": "B"}, headers={"Fiware-ServicePath": header})


# --- malformed input -------------------------------------------------------------------


@pytest.mark.parametrize(
    "body", [b"", b"{", b"nope", b"\xff\xfe", b"[1, 2]", b"5", b"null", b'"x"', b"{}", b'{"data": 5}', b'{"foo": 1}']
)
def test_unusable_bodies(body):
    with pytest.raises(ParseError):
        parse(body)


def test_invalid_json_message():
    with pytest.raises(ParseError, match="not valid JSON"):
        parse(b"{")


MALFORMED = [
    {"data": None},
    {"data": {}},
    {"data": "entities"},
    {"data": [None]},
    {"data": [5]},
    {"data": ["x"]},
    {"data": [[1, 2]]},
    {"data": [[]]},
    {"data": [{}]},
    {"data": [{"id": None}]},
    {"data": [{"id": {"a": 1}}]},
    {"data": [{"id": "x", "type": None}]},
    {"data": [{"id": "x", "a": None}]},
    {"data": [{"id": "x", "a": {"type": None, "value": None}}]},
    {"data": [{"id": "x", "a": {"type": 5, "value": [1]}}]},
    {"data": [{"id": "x", "a": {"type": ["Number"], "value": 1}}]},
    {"data": [{"id": "x", "a": {"type": {"n": 1}, "value": 1, "metadata": 5}}]},
    {"data": [{"id": "x", "a": {"type": "Number", "value": 1, "metadata": {"TimeInstant": 5}}}]},
    {"data": [{"id": "x", "a": {"type": "Number", "value": 1, "metadata": {"TimeInstant": [1]}}}]},
    {"data": [{"id": "x", "a": {"type": "Number", "value": 1, "metadata": []}}]},
    {"data": [{"id": "x", "a": {"type": "geo:point", "value": [1, 2]}}]},
    {"data": [{"id": "x", "a": {"type": "geo:json", "value": {"type": "Point", "coordinates": [[[1]]]}}}]},
    {"data": [{"id": "x", "location": {"type": "Polygon", "coordinates": "x"}}]},
    {"data": [{"id": "x", "a": {"type": "DateTime", "value": {"@value": 5}}}]},
    {"data": [{"id": "x", "TimeInstant": {"type": "DateTime", "value": "99999-01-01"}}]},
    {"data": [{"id": "x", "timestamp": 1e308}]},
    {"data": [{"id": "x", "timestamp": -1e20}]},
    {"data": [{"id": "x", "a": [None, 1, {"type": "Property"}]}]},
    {"data": [{"id": "x", "a": [{"type": "Property"}, {"type": ["Property"]}]}]},
    {"data": [{"id": "x", "a": [{"datasetId": 5, "value": None}]}]},
    {"id": "n", "type": "Notification", "data": None},
    {"id": "n", "type": "Notification", "data": [{"id": "x", "type": [None]}]},
    {"id": "n", "type": "Notification", "data": [{"id": "x", "type": []}]},
    {"id": "n", "type": "Notification", "data": [{"id": "x", "modifiedAt": {"a": 1}}]},
    {
        "id": "n",
        "type": "Notification",
        "data": [{"id": "x", "a": {"type": "Property", "value": {"@type": "DateTime"}}}],
    },
    {"id": "n", "type": "Notification", "data": [{"id": "x", "a": {"type": "Relationship", "object": [1, 2]}}]},
    {"id": "n", "type": "Notification", "data": [{"id": "x", "a": {"type": "GeoProperty", "value": "41, 2"}}]},
    {"id": "n", "type": "Notification", "data": [{"id": "x", "a": {"type": 5, "object": 5, "observedAt": [1]}}]},
    {"id": "n", "type": ["Notification"], "data": [{"id": "x"}]},
    {"contextResponses": None},
    {"contextResponses": [{"contextElement": {"id": "x", "attributes": [{"name": "a", "metadatas": 5}]}}]},
    {
        "contextResponses": [
            {"contextElement": {"id": "x", "attributes": [{"name": "a", "metadatas": [5, {"name": 1}]}]}}
        ]
    },
    {"id": None},
    {"id": ""},
    {"id": "x", "type": 5},
    {"id": "x", "a": {"type": "std_msgs.msg.String", "value": "{%27a%27: (" + "(" * 200 + ")" * 201 + "}"}},
    {"id": "x", "a": {"type": "nav_msgs.msg.Odometry", "value": 5}},
    {"id": "x", "a": {"type": "Number", "value": "1e999"}},
    {"subscriptionId": 5, "data": [["a"]]},
    {"data": [{"id": "x", "deep": [[[[[[[[[[[[[[[[[[[[[[[[[[[[[[1]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]}]},
]


@pytest.mark.parametrize("body", MALFORMED)
@pytest.mark.parametrize("fmt", [None, "normalized", "keyValues", "simplifiedNormalized", "values", "legacy"])
def test_malformed_bodies_raise_only_parse_error(body, fmt):
    headers = {"Ngsiv2-AttrsFormat": fmt} if fmt else {}
    try:
        result = parse(body, headers, values_layout=lambda t, s: ValuesLayout(("id", "a")))
    except ParseError as exc:
        assert exc.description
    else:
        assert isinstance(result, list)


def _random_json(rng: random.Random, depth: int = 0):
    choices = ["null", "bool", "int", "float", "str", "date", "list", "dict"] if depth < 4 else ["null", "int", "str"]
    kind = rng.choice(choices)
    if kind == "null":
        return None
    if kind == "bool":
        return rng.random() < 0.5
    if kind == "int":
        return rng.choice([0, 5, -1, 2**63 - 1, 1714557600123])
    if kind == "float":
        return rng.choice([0.5, -1e300, 1e11, 3.14])
    if kind == "str":
        return rng.choice(
            [
                "",
                "5",
                "id",
                "type",
                "value",
                "Point",
                "41, 2",
                "2024-05-01",
                "urn:x",
                "/a",
                "Notification",
                "geo:point",
                "Number",
                "std_msgs.msg.String",
            ]
        )
    if kind == "date":
        return "2024-05-01T10:00:00+02:00"
    if kind == "list":
        return [_random_json(rng, depth + 1) for _ in range(rng.randint(0, 4))]
    keys = [
        "id",
        "type",
        "value",
        "data",
        "metadata",
        "object",
        "coordinates",
        "datasetId",
        "observedAt",
        "TimeInstant",
        "location",
        "subscriptionId",
        "contextResponses",
        "attributes",
    ]
    return {rng.choice(keys): _random_json(rng, depth + 1) for _ in range(rng.randint(0, 5))}


def _random_body(rng: random.Random):
    """Mostly entity-shaped, so parsing gets past the envelope checks."""
    body = _random_json(rng)
    if rng.random() < 0.6:
        attrs = body if type(body) is dict else {"a": body}
        body = {"id": rng.choice(["E1", "urn:x", ""]), "type": rng.choice(["T", None, ["T"]]), **attrs}
    roll = rng.random()
    if roll < 0.4:
        return {"subscriptionId": "s", "data": [body, _random_json(rng)] if roll < 0.1 else [body]}
    if roll < 0.6:
        return {"type": "Notification", "data": [body]}
    return body


def test_random_shapes_raise_only_parse_error():
    rng = random.Random(20240501)
    formats = [
        None,
        "normalized",
        "keyValues",
        "simplifiedNormalized",
        "simplifiedKeyValues",
        "values",
        "legacy",
        "bogus",
    ]
    parsed = 0
    for _ in range(3000):
        fmt = rng.choice(formats)
        headers = {"Ngsiv2-AttrsFormat": fmt} if fmt else {}
        try:
            result = parse(_random_body(rng), headers, values_layout=lambda t, s: ValuesLayout(("id", "value")))
        except ParseError:
            continue
        assert isinstance(result, list)
        parsed += 1
    assert parsed > 500  # the fuzz must reach attribute parsing, not just envelope errors
