"""A geo-query over whole types is answered from the types' location series
(``ngsild.fetch.Fetcher.located``) and must select exactly the entities the
per-entity path selects: same entities, same attributes, same instances,
whatever the types, datasets, attrs, q and paging. Both backends.

The per-entity path is reached by naming every entity with ``id=``; the
whole-type path by ``type=`` (or by no type at all: a geo-query alone)."""

from __future__ import annotations

import pytest

from tests.ngsild_fixtures import H, get, ld_notify

SITES = {  # id: (type, lon, lat); Madrid's centre is -3.7038, 40.4168
    "urn:ngsi-ld:Sensor:near1": ("Sensor", -3.7040, 40.4170),
    "urn:ngsi-ld:Sensor:near2": ("Sensor", -3.7050, 40.4160),
    "urn:ngsi-ld:Sensor:far": ("Sensor", -3.60, 40.50),
    "urn:ngsi-ld:Robot:near": ("Robot", -3.7030, 40.4165),
    "urn:ngsi-ld:Robot:far": ("Robot", 2.17, 41.38),
}
TIMES = ["2024-05-01T10:00:00Z", "2024-05-01T11:00:00Z", "2024-05-01T12:00:00Z"]
NEAR = {"georel": "near;maxDistance==1000", "geometry": "Point", "coordinates": "[-3.7038, 40.4168]"}


def _entity(eid: str, i: int) -> dict:
    etype, lon, lat = SITES[eid]
    entity = {
        "id": eid,
        "type": etype,
        "temperature": {"type": "Property", "value": 20 + i + len(eid) % 3, "observedAt": TIMES[i]},
    }
    if etype == "Robot":  # the Robots report their place in a second dataset too
        entity["location"] = [
            {"type": "GeoProperty", "value": {"type": "Point", "coordinates": [lon, lat]}, "observedAt": TIMES[i]},
            {
                "type": "GeoProperty",
                "datasetId": "urn:ngsi-ld:Dataset:gps",
                "value": {"type": "Point", "coordinates": [lon + 0.1, lat]},
                "observedAt": TIMES[i],
            },
        ]
    elif i != 1:  # the Sensors skip a location now and then
        entity["location"] = {
            "type": "GeoProperty",
            "value": {"type": "Point", "coordinates": [lon, lat]},
            "observedAt": TIMES[i],
        }
    return entity


@pytest.fixture
def sites(client):
    for i in range(len(TIMES)):
        ld_notify(client, [_entity(eid, i) for eid in SITES], headers={"NGSILD-Tenant": H["NGSILD-Tenant"]})
    return client


def _both(client, by_type: dict, by_ids: dict) -> list:
    whole = get(client, by_type)
    named = get(client, by_ids)
    assert whole.status_code == named.status_code == 200, (whole.text, named.text)
    assert whole.json() == named.json()
    assert whole.headers.get("NGSILD-Results-Count") == named.headers.get("NGSILD-Results-Count")
    return whole.json()


def _ids(etype: str | None = None) -> str:
    return ",".join(eid for eid, site in SITES.items() if etype is None or site[0] == etype)


@pytest.mark.parametrize(
    "extra",
    [
        {},
        {"attrs": "temperature"},
        {"attrs": "location", "datasetId": "urn:ngsi-ld:Dataset:gps"},  # the Sensors have no gps instances
        {"q": "temperature>21", "count": "true"},
        {"timerel": "between", "timeAt": TIMES[1], "endTimeAt": TIMES[2]},  # the Sensors have no place then
        {"lastN": "1", "limit": "1", "offset": "1", "count": "true"},
        {"format": "temporalValues", "attrs": "temperature,location"},
    ],
)
def test_whole_type_matches_what_naming_every_entity_matches(sites, extra):
    found = _both(sites, {"type": "Sensor", **NEAR, **extra}, {"id": _ids("Sensor"), **NEAR, **extra})
    if "timeAt" in extra or "datasetId" in extra:
        assert found == []  # no instance of what is asked in the window: not part of the answer
    elif "offset" not in extra and "q" not in extra:
        assert [e["id"] for e in found] == ["urn:ngsi-ld:Sensor:near1", "urn:ngsi-ld:Sensor:near2"]


def test_several_types_and_no_type(sites):
    everyone = _both(sites, {**NEAR}, {"id": _ids(), **NEAR})
    assert [e["id"] for e in everyone] == [
        "urn:ngsi-ld:Robot:near",
        "urn:ngsi-ld:Sensor:near1",
        "urn:ngsi-ld:Sensor:near2",
    ]
    either = _both(sites, {"type": "Sensor|Robot", **NEAR}, {"id": _ids(), **NEAR})
    assert either == everyone
    assert _both(sites, {"type": "Robot", **NEAR}, {"id": _ids("Robot"), **NEAR})[0]["id"] == "urn:ngsi-ld:Robot:near"


def test_a_type_without_locations_or_unknown_matches_nothing(sites):
    assert get(sites, {"type": "Sensor", **NEAR, "geoproperty": "temperature"}).json() == []
    assert get(sites, {"type": "Nothing", **NEAR}).json() == []
