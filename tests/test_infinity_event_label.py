"""An Infinity event spanning several values is labelled with all of them, in
order, as the SimpleJSON annotations are (``missionState(data) = 1 → 2 → 3``);
it was labelled with its first value only."""

from __future__ import annotations

H = {"Content-Type": "application/json", "Fiware-Service": "drone", "Fiware-ServicePath": "/eprosima"}
DRONE = "urn:ngsiv2:ROS2System:Drone01"
STATES = [0, 1, 2, 2, 3, 0, 4, 4, 0]
RANGE = {"from": "2025-06-02T08:00:00Z", "to": "2025-06-02T10:00:00Z"}


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


def _events(client, **params) -> list[dict]:
    response = client.get("/grafana/infinity/events", params={"id": DRONE, **RANGE, **params}, headers=H)
    assert response.status_code == 200, response.text
    return response.json()


def test_a_run_of_several_states_names_them_all(client, notify):
    _notify(client, notify)
    events = _events(client, attrs="missionState(data)")
    assert [e["text"] for e in events] == [
        f"missionState(data) = 1 → 2 → 3 on {DRONE}",
        f"missionState(data) = 4 on {DRONE}",
    ]
    assert [(e["time"], e["timeEnd"]) for e in events] == [
        ("2025-06-02T09:00:01.000Z", "2025-06-02T09:00:04.000Z"),
        ("2025-06-02T09:00:06.000Z", "2025-06-02T09:00:07.000Z"),
    ]
    assert all(e["title"] == "missionState(data) on Drone01" for e in events)


def test_the_same_run_reads_the_same_in_both_apis(client, notify):
    _notify(client, notify)
    body = {"range": RANGE, "annotation": {"name": "m", "query": f"{DRONE}/missionState(data)"}}
    simplejson = client.post("/grafana/simplejson/annotations", json=body, headers=H).json()
    assert [e["text"] for e in _events(client, attrs="missionState(data)")] == [e["text"] for e in simplejson]


def test_a_condition_and_a_fixed_text_still_win(client, notify):
    _notify(client, notify)
    assert [e["text"] for e in _events(client, attrs="missionState(data)", equals="2")] == [
        f"missionState(data) = 2 on {DRONE}"
    ]
    assert [e["text"] for e in _events(client, attrs="m=missionState(data)", text="mission")] == ["mission"] * 2
