"""Aggregation parameters (ETSI GS CIM 009 V1.9.1 clause 4.5.19, on the
query and retrieve of clauses 6.19 and 6.20): every combination the
clauses allow answers 200 with aggregated values, every attribute with
every method asked (null for the periods of a method that does not apply
to its values); an unknown method or a duration that is none answers the
error type of a parameter outside its grammar (InvalidRequest, as for
``format`` and ``options``; in a ``Query`` body, a TemporalQuery member
not meeting clause 5.2.21: BadRequestData)."""

from __future__ import annotations

import pytest

from tests.ngsild_fixtures import ENTITIES, H, error_type, get

V = "urn:ngsi-ld:Vehicle:agg"
METHODS = ("totalCount", "distinctCount", "sum", "avg", "min", "max", "stddev", "sumsq")
QUERY = "/ngsi-ld/v1/temporal/entityOperations/query"


def at(hour: int) -> str:
    return f"2024-01-{1 + hour // 24:02d}T{hour % 24:02d}:00:00Z"


def series(make) -> list[dict]:
    return [{**make(h), "observedAt": at(h)} for h in range(0, 72, 5)]


@pytest.fixture(scope="module")
def vehicle(client_factory, store_url_factory):
    """Every kind of value: numbers, integers, booleans, text, DateTimes,
    Relationships, LanguageProperties, arrays, objects, geometries, and a
    second dataset."""
    with client_factory(store_url_factory("aggregation_combinations")) as client:
        body = {
            "id": V,
            "type": "Vehicle",
            "speed": [
                *series(lambda h: {"type": "Property", "value": h * 1.5}),
                {"type": "Property", "value": 7, "datasetId": "urn:ngsi-ld:Dataset:b", "observedAt": at(3)},
            ],
            "gear": series(lambda h: {"type": "Property", "value": h % 5}),
            "moving": series(lambda h: {"type": "Property", "value": h % 2 == 0}),
            "label": series(lambda h: {"type": "Property", "value": f"L{h % 3}"}),
            "seen": series(lambda h: {"type": "Property", "value": {"@type": "DateTime", "@value": at(h)}}),
            "owner": series(lambda h: {"type": "Relationship", "object": f"urn:ngsi-ld:Person:{h % 2}"}),
            "name": series(lambda h: {"type": "LanguageProperty", "languageMap": {"en": f"n{h}", "fr": f"m{h}"}}),
            "sizes": series(lambda h: {"type": "Property", "value": list(range(h % 4))}),
            "config": series(lambda h: {"type": "Property", "value": {"k": h}}),
            "location": series(lambda h: {"type": "GeoProperty", "value": {"type": "Point", "coordinates": [h, 0]}}),
        }
        response = client.post(ENTITIES, json=body, headers=H)
        assert response.status_code == 201, response.text
        yield client


ATTRS = ("speed", "gear", "moving", "label", "seen", "owner", "name", "sizes", "config", "location")
WINDOWS = [
    {},
    {"timerel": "before", "timeAt": at(40)},
    {"timerel": "after", "timeAt": at(10)},
    {"timerel": "between", "timeAt": at(5), "endTimeAt": at(60)},
]


def aggregated(entity: dict, methods=METHODS, attrs=ATTRS) -> None:
    """Every attribute has every method, each a list of [value, start, end]."""
    for attr in attrs:
        for item in entity[attr] if isinstance(entity[attr], list) else [entity[attr]]:
            assert item["type"] in ("Property", "Relationship", "GeoProperty", "LanguageProperty"), item
            for method in methods:
                assert isinstance(item[method], list) and item[method], (attr, method, item)
                assert all(len(period) == 3 for period in item[method]), (attr, method)


@pytest.mark.parametrize("window", WINDOWS, ids=["no-timerel", "before", "after", "between"])
@pytest.mark.parametrize("period", [None, "PT0S", "PT6H", "P1D", "P1W", "P1M"])
def test_every_method_on_every_kind_of_value_answers(vehicle, window, period):
    params = {"type": "Vehicle", "format": "aggregatedValues", "aggrMethods": ",".join(METHODS), **window}
    if period:
        params["aggrPeriodDuration"] = period
    [entity] = get(vehicle, params).json()
    aggregated(entity)


def test_a_method_that_does_not_apply_answers_null_for_its_periods(vehicle):
    [entity] = get(vehicle, {"type": "Vehicle", "format": "aggregatedValues", "aggrMethods": "sum,max"}).json()
    assert {v for v, _, _ in entity["owner"]["sum"]} == {None} and {v for v, _, _ in entity["name"]["max"]} == {None}
    assert entity["label"]["max"][0][0] == "L2" and entity["speed"][0]["sum"][0][0] > 0


@pytest.mark.parametrize(
    "extra",
    [
        {"options": "sysAttrs"},
        {"options": "aggregatedValues"},
        {"options": "temporalValues,aggregatedValues"},
        {"options": "concise"},
        {"lang": "fr"},
        {"pick": "id,speed,owner"},
        {"omit": "type,config"},
        {"attrs": "speed,label,owner"},
        {"datasetId": "urn:ngsi-ld:Dataset:b"},
        {"lastN": "3"},
        {"timeproperty": "createdAt"},
        {"count": "true", "limit": "5"},
    ],
)
def test_with_every_other_parameter_the_clauses_allow(vehicle, extra):
    params = {"type": "Vehicle", "aggrMethods": "totalCount,avg,max", **extra}
    if "aggregatedValues" not in extra.get("options", ""):
        params["format"] = "aggregatedValues"
    [entity] = get(vehicle, params).json()
    shown = [a for a in ATTRS if a in entity]
    assert shown, entity
    aggregated(entity, ("totalCount", "avg", "max"), shown)


def test_retrieve_and_query_body(vehicle):
    params = {"format": "aggregatedValues", "aggrMethods": ",".join(METHODS), "aggrPeriodDuration": "P1D"}
    aggregated(get(vehicle, path=f"{ENTITIES}/{V}", params=params).json())
    body = {"type": "Query", "entities": [{"type": "Vehicle"}], "temporalQ": {"aggrMethods": list(METHODS),
            "aggrPeriodDuration": "PT12H", "timerel": "after", "timeAt": at(0)}}  # fmt: skip
    response = vehicle.post(QUERY, json=body, headers=H)
    assert response.status_code == 200, response.text
    aggregated(response.json()[0])


@pytest.mark.parametrize(
    "params",
    [
        {"aggrMethods": "median"},
        {"aggrMethods": "sum,Sum"},
        {"aggrMethods": "sum", "aggrPeriodDuration": "1 hour"},
        {"aggrMethods": "sum", "aggrPeriodDuration": "PT"},
        {"aggrMethods": "sum", "aggrPeriodDuration": "-P1D"},
        {"aggrMethods": "sum", "aggrPeriodDuration": "P1.5D"},
    ],
)
def test_an_unknown_method_or_a_duration_that_is_none_is_an_invalid_request(vehicle, params):
    """Query string: a parameter value outside its grammar (InvalidRequest);
    Query body: a TemporalQuery member not meeting clause 5.2.21 (BadRequestData)."""
    response = get(vehicle, {"type": "Vehicle", "format": "aggregatedValues", **params}, status=400)
    assert error_type(response) == "InvalidRequest"
    retrieve = get(vehicle, path=f"{ENTITIES}/{V}", params={"format": "aggregatedValues", **params}, status=400)
    assert error_type(retrieve) == "InvalidRequest"
    body = {"type": "Query", "entities": [{"type": "Vehicle"}], "temporalQ": params}
    response = vehicle.post(QUERY, json=body, headers=H)
    assert response.status_code == 400 and error_type(response) == "BadRequestData"
