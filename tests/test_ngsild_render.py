"""The temporal representations (clauses 4.5.7-4.5.9): normalized members
per attribute type, the simplified (temporalValues) pairs, and 206 Partial
Content past the instance cap, paging forwards or, with lastN, backwards."""

from __future__ import annotations

import pytest

from tests.ngsild_fixtures import A8311, B9211, ENTITIES, H, get, load_vehicles


@pytest.fixture
def vehicles(client):
    load_vehicles(client)
    return client


def test_normalized_members_per_attribute_type(vehicles):
    got = get(vehicles, path=f"{ENTITIES}/{B9211}").json()
    assert got["isParked"][0]["type"] == "Relationship"
    assert got["isParked"][0]["object"] == "urn:ngsi-ld:OffStreetParking:0"
    assert got["name"][1]["type"] == "LanguageProperty"
    assert got["name"][1]["languageMap"] == {"en": "car 1", "es": "coche 1"}
    assert got["location"][0]["type"] == "GeoProperty"
    assert got["location"][0]["value"] == {"type": "Point", "coordinates": [-3.7038, 40.4168]}
    assert got["brandName"][2]["value"] == "brand2"
    assert all("instanceId" in i and "observedAt" in i for attr in ("speed", "name", "isParked") for i in got[attr])


def test_simplified_temporal_values(vehicles):
    got = get(vehicles, path=f"{ENTITIES}/{A8311}", params={"options": "temporalValues"}).json()
    assert got["speed"] == {
        "type": "Property",
        "values": [
            [40, "2018-08-01T12:12:00Z"],
            [60, "2018-08-01T12:14:00Z"],
            [50, "2018-08-01T12:16:00Z"],
        ],
    }
    assert got["isParked"]["objects"][0] == ["urn:ngsi-ld:OffStreetParking:0", "2018-08-01T12:12:00Z"]
    assert got["name"]["languageMaps"][2] == [{"languageMap": {"en": "car 2", "es": "coche 2"}}, "2018-08-01T12:16:00Z"]
    assert got["location"]["type"] == "GeoProperty" and len(got["location"]["values"]) == 3
    same = get(vehicles, path=f"{ENTITIES}/{A8311}", params={"format": "temporalValues", "options": "normalized"})
    assert same.json() == got


def test_partial_content_forwards(client_factory, store_url):
    with client_factory(store_url, ngsild_max_instances=4) as client:
        load_vehicles(client)
        response = get(client, path=f"{ENTITIES}/{B9211}", params={"attrs": "speed,brandName"}, status=206)
        got = response.json()
        assert [i["value"] for i in got["speed"]] == [120, 80] and len(got["brandName"]) == 2
        assert response.headers["Content-Range"] == "date-time 2018-08-01T12:03:00Z-2018-08-01T12:05:00Z/*"
        # The newer drafts' link to the rest: from the first instant not served, nothing twice.
        rest = _link(response, "intervalafter")
        assert rest.startswith(f"{ENTITIES}/{B9211}?") and "timerel=after&timeAt=2018-08-01T12%3A07%3A00Z" in rest
        assert [i["value"] for i in client.get(rest, headers=H).json()["speed"]] == [100]
        windowed = get(
            client,
            path=f"{ENTITIES}/{B9211}",
            status=206,
            params={"attrs": "speed,brandName", "timerel": "after", "timeAt": "2018-08-01T12:00:00Z"},
        )
        assert windowed.headers["Content-Range"] == "date-time 2018-08-01T12:00:00Z-2018-08-01T12:05:00Z/*"
        between = get(
            client,
            path=f"{ENTITIES}/{B9211}",
            status=206,
            params={"attrs": "speed,brandName", "timerel": "before", "timeAt": "2018-08-01T12:30:00Z"},
        )
        assert "timerel=between&timeAt=2018-08-01T12%3A07%3A00Z&endTimeAt=2018-08-01T12%3A30%3A00Z" in _link(
            between, "intervalafter"
        )
        whole = get(client, path=f"{ENTITIES}/{B9211}", params={"attrs": "speed"})
        assert "Content-Range" not in whole.headers


def test_partial_content_backwards_with_last_n(client_factory, store_url):
    with client_factory(store_url, ngsild_max_instances=4) as client:
        load_vehicles(client)
        response = get(
            client, path=f"{ENTITIES}/{B9211}", params={"attrs": "speed,brandName", "lastN": "3"}, status=206
        )
        got = response.json()
        assert [i["value"] for i in got["speed"]] == [80, 100]
        assert response.headers["Content-Range"] == "date-time 2018-08-01T12:07:00Z-2018-08-01T12:05:00Z/3"
        rest = _link(response, "intervalbefore")
        assert "lastN=3" in rest and "timerel=before&timeAt=2018-08-01T12%3A05%3A00Z" in rest
        assert [i["value"] for i in client.get(rest, headers=H).json()["speed"]] == [120]


def _link(response, rel: str) -> str:
    """The target of the ``Link`` with relation ``rel``."""
    for part in response.headers["Link"].split(", <"):
        if f'rel="{rel}"' in part:
            return part.lstrip("<").split(">;")[0]
    raise AssertionError(f"no {rel} link in {response.headers['Link']}")
