"""A SimpleJSON annotation spanning several values is labelled with all of
them, in order (it was labelled with the first only: a drone mission that
went taking off → flying → reading read "missionState = 1")."""

from __future__ import annotations

H = {"Content-Type": "application/json", "Fiware-Service": "drone", "Fiware-ServicePath": "/eprosima"}
DRONE = "urn:ngsiv2:ROS2System:Drone01"
STATES = [0, 1, 2, 2, 3, 0, 4, 4, 0]


def _notify(client, notify):
    for i, state in enumerate(STATES):
        notify(
            client,
            {
                "subscriptionId": "s",
                "data": [
                    {
                        "id": DRONE,
                        "type": "ROS2System",
                        "missionState": {"type": "Object", "value": {"data": state}},
                        "TimeInstant": {"type": "DateTime", "value": f"2025-06-02T09:00:{i:02d}.000Z"},
                    }
                ],
            },
            H,
        )


def _annotations(client, query: str) -> list[dict]:
    body = {
        "range": {"from": "2025-06-02T08:00:00Z", "to": "2025-06-02T10:00:00Z"},
        "annotation": {"name": "missions", "query": query},
    }
    response = client.post("/grafana/simplejson/annotations", json=body, headers=H)
    assert response.status_code == 200, response.text
    return response.json()


def test_a_run_of_several_states_names_them_all(client, notify):
    _notify(client, notify)
    events = _annotations(client, f"{DRONE}/missionState(data)")
    assert [e["text"] for e in events] == [
        f"missionState(data) = 1 → 2 → 3 on {DRONE}",
        f"missionState(data) = 4 on {DRONE}",
    ]
    assert [(e["time"], e["timeEnd"], e["isRegion"]) for e in events] == [
        (1748854801000, 1748854804000, True),
        (1748854806000, 1748854807000, True),
    ]
    assert all(e["title"] == "missionState(data) on Drone01" for e in events)


def test_a_condition_still_selects_one_value(client, notify):
    _notify(client, notify)
    events = _annotations(client, f"{DRONE}/missionState(data)=2")
    assert [(e["text"], e["timeEnd"] - e["time"]) for e in events] == [(f"missionState(data) = 2 on {DRONE}", 1000)]
