"""Data for the NGSI-LD temporal read tests, stored the way a broker sends
it: NGSI-LD notifications (Orion-LD) on ``POST /ngsi-ld/v1/notify`` and, for
the "NGSIv2 data is plain Properties" tests, NGSIv2 notifications.

The vehicles follow the spec's annex C.5 examples: Vehicle B9211 observed
at 12:03, 12:05 and 12:07 on 2018-08-01, Vehicle A8311 at 12:12, 12:14, 12:16.
"""

from __future__ import annotations

TENANT = "fleet"
H = {"Content-Type": "application/json", "NGSILD-Tenant": TENANT}
B9211 = "urn:ngsi-ld:Vehicle:B9211"
A8311 = "urn:ngsi-ld:Vehicle:A8311"
SPEEDS = {
    B9211: [(120, "2018-08-01T12:03:00Z"), (80, "2018-08-01T12:05:00Z"), (100, "2018-08-01T12:07:00Z")],
    A8311: [(40, "2018-08-01T12:12:00Z"), (60, "2018-08-01T12:14:00Z"), (50, "2018-08-01T12:16:00Z")],
}
PLACES = {B9211: [-3.7038, 40.4168], A8311: [2.1734, 41.3851]}  # Madrid, Barcelona (lon, lat)
_counter = [0]


def ld_notify(client, entities: list[dict], headers: dict | None = None) -> None:
    _counter[0] += 1
    body = {
        "id": f"urn:ngsi-ld:Notification:{_counter[0]}",
        "type": "Notification",
        "subscriptionId": "urn:ngsi-ld:Subscription:temporal",
        "notifiedAt": "2018-08-01T13:00:00Z",
        "data": entities,
    }
    response = client.post("/ngsi-ld/v1/notify", json=body, headers={**H, **(headers or {})})
    assert response.status_code == 200, response.text


def load_vehicles(client) -> None:
    """Three speed instances per vehicle, a location, a relationship, a
    brand name (text) and a languageMap, each with its own observedAt."""
    for vid, samples in SPEEDS.items():
        for i, (speed, at) in enumerate(samples):
            ld_notify(
                client,
                [
                    {
                        "id": vid,
                        "type": "Vehicle",
                        "speed": {"type": "Property", "value": speed, "observedAt": at, "unitCode": "KMH"},
                        "location": {
                            "type": "GeoProperty",
                            "observedAt": at,
                            "value": {"type": "Point", "coordinates": [PLACES[vid][0] + i * 0.001, PLACES[vid][1]]},
                        },
                        "isParked": {
                            "type": "Relationship",
                            "object": f"urn:ngsi-ld:OffStreetParking:{i}",
                            "observedAt": at,
                        },
                        "brandName": {"type": "Property", "value": f"brand{i}", "observedAt": at},
                        "name": {
                            "type": "LanguageProperty",
                            "languageMap": {"en": f"car {i}", "es": f"coche {i}"},
                            "observedAt": at,
                        },
                    }
                ],
            )


ENTITIES = "/ngsi-ld/v1/temporal/entities"


def get(client, params: dict | None = None, path: str = ENTITIES, headers: dict | None = None, status: int = 200):
    response = client.get(path, params=params or {}, headers={**H, **(headers or {})})
    assert response.status_code == status, response.text
    return response


def error_type(response) -> str:
    """The NGSI-LD error type of an error answer (ProblemDetails ``type``,
    or the NGSI ``error`` name)."""
    body = response.json()
    return str(body.get("type") or body.get("error")).rsplit("/", 1)[-1]


def ids(response) -> list[str]:
    return [e["id"] for e in response.json()]
