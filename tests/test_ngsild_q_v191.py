"""The query language (ETSI GS CIM 009 V1.9.1 clause 4.9) over the temporal
window, where V1.9.1 says more than the main suite checks: ``!attr``,
array values, Relationships and ordering, LanguageProperty members, and
linked-entity projection refused. Each rule over real storage, both
backends; a term holds when some instance of its attribute in the window
satisfies it."""

from __future__ import annotations

import pytest

from tests.ngsild_fixtures import ENTITIES, H, error_type, get, ids

A = "urn:ngsi-ld:Thing:a"
B = "urn:ngsi-ld:Thing:b"
C = "urn:ngsi-ld:Thing:c"
AT = "2024-01-01T00:00:00Z"


def prop(value, **extra) -> list[dict]:
    return [{"type": "Property", "value": value, "observedAt": AT, **extra}]


@pytest.fixture
def things(client):
    bodies = [
        {
            "id": A,
            "type": "Thing",
            "tags": prop(["a", "b"]),
            "sizes": prop([1, 5, 9]),
            "speed": prop(5),
            "owner": [{"type": "Relationship", "object": "urn:ngsi-ld:Person:9", "observedAt": AT}],
            "name": [{"type": "LanguageProperty", "languageMap": {"en": "Car", "fr": "Voiture"}, "observedAt": AT}],
            "reading": prop(3, source={"type": "Relationship", "object": "urn:ngsi-ld:Sensor:z"}),
        },
        {"id": B, "type": "Thing", "tags": prop(["c"]), "sizes": prop([2]), "speed": prop(1)},
        {"id": C, "type": "Thing", "speed": prop(5), "label": prop("urn:ngsi-ld:Person:9")},
    ]
    for body in bodies:
        response = client.post(ENTITIES, json=body, headers=H)
        assert response.status_code == 201, response.text
    return client


def q(client, expr: str, **more) -> list[str]:
    return ids(get(client, {"type": "Thing", "q": expr, **more}))


def test_not_attr_holds_where_the_attribute_has_no_value_in_a_conjunction(things):
    """Clause 4.9: !attr (the attribute does not exist), combined with ; and |."""
    assert q(things, "!tags") == [C]
    assert q(things, "!tags;speed==5") == [C]
    assert q(things, "speed==5;!owner") == [C]
    assert q(things, "!owner|speed==1") == [B, C]
    assert q(things, "(!tags|!owner);speed==5") == [C]


def test_an_array_matches_when_one_of_its_elements_does(things):
    """Clause 4.9: a value that is an array matches a term when one of its
    elements does, for equality, lists, ranges and order alike."""
    assert q(things, 'tags=="a"') == [A]
    assert q(things, 'tags=="a","c"') == [A, B]
    assert q(things, "sizes>8") == [A]
    assert q(things, "sizes==2..4") == [B]
    assert q(things, 'tags~="^c"') == [B]


def test_not_equal_against_an_array_holds_only_when_no_element_equals(things):
    """Clause 4.9: != against an array: none of its elements is equal."""
    assert q(things, 'tags!="a"') == [B]
    assert q(things, 'tags!="z"') == [A, B]
    assert q(things, "sizes!=5") == [B]
    assert q(things, 'tags!~="^[ab]"') == [B]


def test_ordering_operators_never_match_a_relationship(things):
    """Clause 4.9: <, <=, >, >= compare values, never a Relationship's
    object, the attribute's or a sub-relationship's; equality does."""
    assert q(things, 'owner>"urn:a"') == []
    assert q(things, 'owner<="urn:z"') == []
    assert q(things, 'owner=="urn:ngsi-ld:Person:9"') == [A]
    assert q(things, 'reading.source>"urn:a"') == []
    assert q(things, 'reading.source=="urn:ngsi-ld:Sensor:z"') == [A]
    assert q(things, 'label>"urn:a"') == [C]  # the same text as a Property's value is ordered


def test_language_property_members_and_the_wildcard(things):
    """Clause 4.9: name[en] is a LanguageProperty's English string,
    name[*] any of its strings; a[b][c] is the same path as a[b.c]."""
    assert q(things, 'name[en]=="Car"') == [A]
    assert q(things, 'name[fr]=="Car"') == []
    assert q(things, 'name[*]=="Voiture"') == [A]
    assert q(things, 'name[*]~="^Vo"') == [A]
    assert q(things, 'name[*]!="Car"') == []


def test_linked_entity_projection_is_refused(things):
    """The temporal API has no linked-entity retrieval (V1.9.1's
    ``{...}`` projection): 400 BadRequestData, not an empty answer, on the
    query, the retrieve and a Query body."""
    for params in ({"q": 'owner{name}=="x"'}, {"pick": "owner{name}"}, {"omit": "id,owner{name}"}):
        assert error_type(get(things, {"type": "Thing", **params}, status=400)) == "BadRequestData"
        retrieve = get(things, path=f"{ENTITIES}/{A}", params=params, status=400)
        assert error_type(retrieve) == "BadRequestData"
    body = {"type": "Query", "entities": [{"type": "Thing"}], "q": 'owner{name}=="x"'}
    response = things.post("/ngsi-ld/v1/temporal/entityOperations/query", json=body, headers=H)
    assert response.status_code == 400 and error_type(response) == "BadRequestData"
