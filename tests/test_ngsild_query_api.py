"""GET /ngsi-ld/v1/temporal/entities and /temporal/entities/{id}: the
temporal query parameters of clauses 6.18.3.2 and 6.19.3.1 on stored
NGSI-LD notifications, on both backends."""

from __future__ import annotations

import pytest

from tests.ngsild_fixtures import (
    A8311,
    B9211,
    ENTITIES,
    H,
    error_type,
    get,
    ids,
    ld_notify,
    load_vehicles,
)


@pytest.fixture(scope="module")
def vehicles(client_factory, store_url_factory):
    """The vehicles, one store per backend; the tests that take it only read."""
    with client_factory(store_url_factory("vehicles")) as client:
        load_vehicles(client)
        yield client


def speeds(entity: dict) -> list:
    return [(i["value"], i["observedAt"]) for i in entity.get("speed", [])]


def test_timerel_before_after_between_are_half_open(vehicles):
    before = get(vehicles, {"type": "Vehicle", "attrs": "speed", "timerel": "before", "timeAt": "2018-08-01T12:05:00Z"})
    # An entity without an instance of what is asked in the window is not part of the answer.
    assert [speeds(e) for e in before.json()] == [[(120, "2018-08-01T12:03:00Z")]]
    after = get(vehicles, {"type": "Vehicle", "attrs": "speed", "timerel": "after", "timeAt": "2018-08-01T12:14:00Z"})
    assert [[v for v, _ in speeds(e)] for e in after.json()] == [[60, 50]]
    between = get(
        vehicles,
        {
            "type": "Vehicle",
            "attrs": "speed",
            "timerel": "between",
            "timeAt": "2018-08-01T12:05:00Z",
            "endTimeAt": "2018-08-01T12:14:00Z",
        },
    )
    assert [[v for v, _ in speeds(e)] for e in between.json()] == [[40], [80, 100]]


def test_normalized_instances_carry_instance_id_observed_at_and_sub_properties(vehicles):
    entity = get(vehicles, path=f"{ENTITIES}/{B9211}", params={"attrs": "speed"}).json()
    assert entity["id"] == B9211 and entity["type"] == "Vehicle"
    first = entity["speed"][0]
    assert first["type"] == "Property" and first["value"] == 120 and first["unitCode"] == "KMH"
    assert first["observedAt"] == "2018-08-01T12:03:00Z"
    assert first["instanceId"].startswith("urn:ngsi-ld:attribute:instance:")
    assert len({i["instanceId"] for i in entity["speed"]}) == 3
    again = get(vehicles, path=f"{ENTITIES}/{B9211}", params={"attrs": "speed"}).json()
    assert again["speed"] == entity["speed"]  # stable instance ids


def test_last_n_is_per_attribute_per_entity(vehicles):
    got = get(vehicles, {"type": "Vehicle", "attrs": "speed,brandName", "lastN": "2"}).json()
    assert [[v for v, _ in speeds(e)] for e in got] == [[60, 50], [80, 100]]
    assert [len(e["brandName"]) for e in got] == [2, 2]


def test_first_n_is_the_oldest_per_attribute_per_entity(vehicles):
    got = get(vehicles, {"type": "Vehicle", "attrs": "speed,brandName", "firstN": "2"}).json()
    assert [[v for v, _ in speeds(e)] for e in got] == [[40, 60], [120, 80]]
    assert [len(e["brandName"]) for e in got] == [2, 2]
    both = get(vehicles, {"type": "Vehicle", "lastN": "1", "firstN": "1"}, status=400)
    assert error_type(both) == "BadRequestData"
    second = get(vehicles, {"type": "Vehicle", "attrs": "speed", "firstN": "1", "offsetN": "1"}).json()
    assert [[v for v, _ in speeds(e)] for e in second] == [[60], [80]]  # TS 104 176 clause 6.4.7.3


def test_ids_id_pattern_and_type_expressions(vehicles):
    assert ids(get(vehicles, {"type": "Vehicle", "id": A8311})) == [A8311]
    assert ids(get(vehicles, {"type": "Vehicle", "idPattern": "B92"})) == [B9211]
    assert ids(get(vehicles, {"type": "Car|Vehicle"})) == [A8311, B9211]
    assert ids(get(vehicles, {"type": "(Car,Vehicle);Vehicle"})) == [A8311, B9211]
    assert ids(get(vehicles, {"type": "Car;Vehicle"})) == []
    assert ids(get(vehicles, {"type": "Car"})) == []
    assert ids(get(vehicles, {"attrs": "brandName"})) == [A8311, B9211]
    assert ids(get(vehicles, {"attrs": "nothing"})) == []


def test_pick_and_omit(vehicles):
    got = get(vehicles, {"type": "Vehicle", "pick": "id,speed", "id": B9211}).json()[0]
    assert set(got) == {"id", "speed"}
    got = get(vehicles, {"type": "Vehicle", "omit": "type,speed,location,name", "id": B9211}).json()[0]
    assert set(got) == {"id", "brandName", "isParked"}


def test_q_is_evaluated_over_the_instances_in_the_window(vehicles):
    assert ids(get(vehicles, {"type": "Vehicle", "q": "speed>100"})) == [B9211]
    late = {"timerel": "after", "timeAt": "2018-08-01T12:04:00Z"}
    assert ids(get(vehicles, {"type": "Vehicle", "q": "speed>100", **late})) == []
    assert ids(get(vehicles, {"type": "Vehicle", "q": "speed==80|speed==60"})) == [A8311, B9211]
    assert ids(get(vehicles, {"type": "Vehicle", "q": 'speed==80;brandName=="brand0"'})) == [B9211]
    assert ids(get(vehicles, {"type": "Vehicle", "q": 'speed.unitCode=="KMH";speed<45'})) == [A8311]
    assert ids(get(vehicles, {"type": "Vehicle", "q": 'name[es]=="coche 2"'})) == [A8311, B9211]
    assert ids(get(vehicles, {"type": "Vehicle", "q": "isParked==urn:ngsi-ld:OffStreetParking:2"})) == [A8311, B9211]
    assert ids(get(vehicles, {"type": "Vehicle", "q": 'brandName~="^brand[12]$";speed>=100'})) == [B9211]
    assert ids(get(vehicles, {"type": "Vehicle", "q": "speed!=120"})) == [A8311, B9211]
    assert ids(get(vehicles, {"type": "Vehicle", "q": "speed==100..130"})) == [B9211]
    assert ids(get(vehicles, {"q": "missing"})) == []


def test_geo_query_over_the_window(vehicles):
    near_madrid = {"georel": "near;maxDistance==500", "geometry": "Point", "coordinates": "[-3.7038, 40.4168]"}
    assert ids(get(vehicles, {"type": "Vehicle", **near_madrid})) == [B9211]
    # the vehicle's later positions moved ~85 m east per step; 100 m catches only the first
    tight = {"georel": "near;maxDistance==50", "geometry": "Point", "coordinates": "[-3.7018, 40.4168]"}
    assert ids(get(vehicles, {"type": "Vehicle", **tight})) == [B9211]
    assert ids(get(vehicles, {"type": "Vehicle", **tight, "timerel": "before", "timeAt": "2018-08-01T12:06:00Z"})) == []
    barcelona = "[[[2.1, 41.3], [2.3, 41.3], [2.3, 41.5], [2.1, 41.5], [2.1, 41.3]]]"
    assert ids(
        get(vehicles, {"type": "Vehicle", "georel": "within", "geometry": "Polygon", "coordinates": barcelona})
    ) == [A8311]
    assert ids(
        get(vehicles, {"type": "Vehicle", "georel": "disjoint", "geometry": "Polygon", "coordinates": barcelona})
    ) == [B9211]
    far = {"georel": "near;minDistance==100000", "geometry": "Point", "coordinates": "[-3.7038, 40.4168]"}
    assert ids(get(vehicles, {"type": "Vehicle", **far})) == [A8311]
    assert ids(get(vehicles, {"type": "Vehicle", **near_madrid, "geoproperty": "speed"})) == []


def test_limit_offset_count_and_links(vehicles):
    first = get(vehicles, {"type": "Vehicle", "limit": "1", "count": "true", "attrs": "speed"})
    assert ids(first) == [A8311] and first.headers["NGSILD-Results-Count"] == "2"
    assert 'rel="next"' in first.headers["Link"] and "offset=1" in first.headers["Link"]
    second = get(vehicles, {"type": "Vehicle", "limit": "1", "offset": "1", "attrs": "speed", "orderBy": "id"})
    assert ids(second) == [B9211] and 'rel="prev"' in second.headers["Link"]
    assert "NGSILD-Results-Count" not in second.headers
    only_count = get(vehicles, {"type": "Vehicle", "limit": "0", "count": "true"})
    assert only_count.json() == [] and only_count.headers["NGSILD-Results-Count"] == "2"


def test_dataset_ids(client):
    for speed, source, at in [
        (10, None, "12:00"),
        (11, "urn:ngsi-ld:Dataset:gps", "12:01"),
        (12, "urn:ngsi-ld:Dataset:gps", "12:02"),
    ]:
        attr = {"type": "Property", "value": speed, "observedAt": f"2018-08-01T{at}:00Z"}
        if source:
            attr["datasetId"] = source
        ld_notify(client, [{"id": B9211, "type": "Vehicle", "speed": attr}])
    every = get(client, {"type": "Vehicle"}).json()[0]["speed"]
    assert [(i["value"], i.get("datasetId")) for i in every] == [
        (10, None),
        (11, "urn:ngsi-ld:Dataset:gps"),
        (12, "urn:ngsi-ld:Dataset:gps"),
    ]
    gps = get(client, {"type": "Vehicle", "datasetId": "urn:ngsi-ld:Dataset:gps"}).json()[0]["speed"]
    assert [i["value"] for i in gps] == [11, 12]
    default = get(client, {"type": "Vehicle", "datasetId": "@none"}).json()[0]["speed"]
    assert [i["value"] for i in default] == [10]
    simplified = get(client, {"type": "Vehicle", "format": "temporalValues"}).json()[0]["speed"]
    assert simplified == [
        {"type": "Property", "values": [[10, "2018-08-01T12:00:00Z"]]},
        {
            "type": "Property",
            "values": [[11, "2018-08-01T12:01:00Z"], [12, "2018-08-01T12:02:00Z"]],
            "datasetId": "urn:ngsi-ld:Dataset:gps",
        },
    ]


def test_time_properties_and_sys_attrs(client):
    ld_notify(
        client,
        [
            {
                "id": B9211,
                "type": "Vehicle",
                "speed": {
                    "type": "Property",
                    "value": 5,
                    "observedAt": "2018-08-01T12:00:00Z",
                    "createdAt": "2018-08-01T11:00:00Z",
                    "modifiedAt": "2018-08-01T12:00:01Z",
                },
            }
        ],
    )
    ld_notify(
        client,
        [
            {
                "id": B9211,
                "type": "Vehicle",
                "speed": {"type": "Property", "value": "urn:ngsi-ld:null", "deletedAt": "2018-08-01T13:00:00Z"},
            }
        ],
    )
    plain = get(client, {"type": "Vehicle"}).json()[0]["speed"]
    assert "createdAt" not in plain[0] and plain[-1]["value"] == "urn:ngsi-ld:null"
    assert plain[-1]["deletedAt"] == "2018-08-01T13:00:00Z"
    sys = get(client, {"type": "Vehicle", "options": "sysAttrs"}).json()[0]["speed"][0]
    assert (sys["createdAt"], sys["modifiedAt"]) == ("2018-08-01T11:00:00Z", "2018-08-01T12:00:01Z")
    created = get(
        client, {"type": "Vehicle", "timeproperty": "createdAt", "timerel": "before", "timeAt": "2018-08-01T11:30:00Z"}
    ).json()[0]["speed"]
    assert [i["value"] for i in created] == [5]
    deleted = get(
        client, {"type": "Vehicle", "timeproperty": "deletedAt", "timerel": "after", "timeAt": "2018-08-01T00:00:00Z"}
    ).json()[0]["speed"]
    assert [i["value"] for i in deleted] == ["urn:ngsi-ld:null"]


def test_ngsiv2_data_reads_as_plain_properties(client, notify):
    body = {
        "subscriptionId": "s",
        "data": [
            {
                "id": "Drone:1",
                "type": "Drone",
                "altitude": {
                    "type": "Number",
                    "value": 12.5,
                    "metadata": {"accuracy": {"type": "Number", "value": 0.5}},
                },
                "owner": {"type": "Relationship", "value": "Company:1"},
                "location": {"type": "geo:json", "value": {"type": "Point", "coordinates": [8.68, 49.41]}},
                "TimeInstant": {"type": "DateTime", "value": "2024-05-01T10:00:00Z"},
            }
        ],
    }
    notify(client, body, {"Fiware-Service": "fleet"})
    got = get(client, path=f"{ENTITIES}/Drone:1").json()
    assert got["type"] == "Drone"
    assert got["altitude"][0] == {
        "type": "Property",
        "value": 12.5,
        "accuracy": {"type": "Property", "value": 0.5},
        "instanceId": got["altitude"][0]["instanceId"],
        "observedAt": "2024-05-01T10:00:00Z",
    }
    assert got["owner"][0]["type"] == "Relationship" and got["owner"][0]["object"] == "Company:1"
    assert got["location"][0]["type"] == "GeoProperty"
    near = {"georel": "near;maxDistance==10", "geometry": "Point", "coordinates": "[8.68, 49.41]"}
    assert ids(get(client, {"type": "Drone", **near})) == ["Drone:1"]


def test_post_entity_operations_query(vehicles):
    body = {
        "type": "Query",
        "entities": [{"type": "Vehicle"}],
        "attrs": ["speed"],
        "q": "speed>=60",
        "temporalQ": {"timerel": "between", "timeAt": "2018-08-01T12:00:00Z", "endTimeAt": "2018-08-01T12:20:00Z"},
    }
    response = vehicles.post(
        "/ngsi-ld/v1/temporal/entityOperations/query",
        json=body,
        params={"options": "temporalValues", "lastN": "1"},
        headers=H,
    )
    assert response.status_code == 200, response.text
    assert [(e["id"], e["speed"]["values"]) for e in response.json()] == [
        (A8311, [[50, "2018-08-01T12:16:00Z"]]),
        (B9211, [[100, "2018-08-01T12:07:00Z"]]),
    ]
    bad = vehicles.post("/ngsi-ld/v1/temporal/entityOperations/query", content=b"{", headers=H)
    assert bad.status_code == 400 and error_type(bad) == "InvalidRequest"


def test_errors(vehicles):
    missing = get(vehicles, path=f"{ENTITIES}/urn:ngsi-ld:Vehicle:none", status=404)
    assert error_type(missing) == "ResourceNotFound"
    assert missing.json()["type"] == "https://uri.etsi.org/ngsi-ld/errors/ResourceNotFound"
    assert missing.json()["status"] == 404 and missing.json()["detail"]
    assert error_type(get(vehicles, {}, status=400)) == "BadRequestData"
    assert (
        error_type(get(vehicles, {"type": "Vehicle", "timerel": "later", "timeAt": "x"}, status=400))
        == "BadRequestData"
    )
    unknown_tenant = get(vehicles, {"type": "Vehicle"}, headers={"NGSILD-Tenant": "nobody"}, status=404)
    assert error_type(unknown_tenant) == "NonexistentTenant"
    assert ids(get(vehicles, {"type": "Vehicle"}, headers={"NGSILD-Tenant": ""})) == []
    not_acceptable = get(vehicles, {"type": "Vehicle"}, headers={"Accept": "text/html"}, status=406)
    assert error_type(not_acceptable) == "NotAcceptable"


def test_retrieve_merges_nothing_across_tenants(vehicles):
    get(vehicles, path=f"{ENTITIES}/{B9211}", headers={"NGSILD-Tenant": "other"}, status=404)


def test_temporal_writes_read_back(client):
    entity = {
        "id": "urn:ngsi-ld:Vehicle:W1",
        "type": "Vehicle",
        "speed": [
            {"type": "Property", "value": 7, "observedAt": "2020-01-01T00:00:00Z"},
            {"type": "Property", "value": 8, "observedAt": "2020-01-01T00:01:00Z"},
        ],
    }
    created = client.post(ENTITIES, json=entity, headers=H)
    assert created.status_code == 201, created.text  # a new entity
    got = get(client, path=f"{ENTITIES}/urn:ngsi-ld:Vehicle:W1", params={"format": "temporalValues"}).json()
    assert got["speed"]["values"] == [[7, "2020-01-01T00:00:00Z"], [8, "2020-01-01T00:01:00Z"]]


def test_q_and_geo_over_scattered_series(client):
    """Entities with many attributes put one attribute's series far apart
    (DuckDB reads such a set one series per UNION ALL branch): same answers."""
    for n in range(5):
        attrs = {f"extra{k}": {"type": "Property", "value": k, "observedAt": "2024-01-01T00:00:00Z"} for k in range(9)}
        ld_notify(
            client,
            [
                {
                    "id": f"urn:ngsi-ld:Robot:{n}",
                    "type": "Robot",
                    **attrs,
                    "speed": {"type": "Property", "value": n, "observedAt": "2024-01-01T00:00:00Z"},
                    "location": {
                        "type": "GeoProperty",
                        "observedAt": "2024-01-01T00:00:00Z",
                        "value": {"type": "Point", "coordinates": [n * 0.01, 0.0]},
                    },
                }
            ],
        )
    fast = get(client, {"type": "Robot", "attrs": "speed", "q": "speed>=2"})
    assert ids(fast) == [f"urn:ngsi-ld:Robot:{n}" for n in (2, 3, 4)]
    near = get(
        client,
        {
            "type": "Robot",
            "attrs": "speed",
            "q": "speed!=3",
            "georel": "near;maxDistance==1500",
            "geometry": "Point",
            "coordinates": "[0.03, 0.0]",
        },
    )
    assert ids(near) == [f"urn:ngsi-ld:Robot:{n}" for n in (2, 4)]


def test_read_budget_is_too_complex_query(client_factory, store_url):
    """A type query over more series than a request may read (TSDB_READ_MAX_SERIES)
    is refused before any sample is read, as NGSI-LD's TooComplexQuery."""
    with client_factory(store_url, read_max_series=6) as client:
        load_vehicles(client)
        response = get(client, {"type": "Vehicle"}, status=422)
        assert error_type(response) == "TooComplexQuery" and "TSDB_READ_MAX_SERIES" in response.json()["detail"]
        assert len(get(client, {"type": "Vehicle", "id": B9211, "attrs": "speed"}).json()) == 1
