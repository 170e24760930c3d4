"""The SimpleJSON family over real HTTP: classic SimpleJSON and simPod JSON.

Request bodies are the ones the plugins send: classic SimpleJSON posts
Grafana's query options with ``type: timeserie|table`` targets and its own
``/search`` and ``/annotations`` bodies; simPod posts Grafana's whole
``DataQueryRequest`` (``app``, ``requestId``, ``scopedVars``, targets with a
``payload`` object, ``datasource``, ``editorMode`` ...) and its ``/variable``,
``/metrics`` and ``/metric-payload-options`` bodies. Unknown keys must not
matter; bad input is a 400 in the NGSI shape, never a 500.
"""

from __future__ import annotations

from datetime import UTC, datetime, timedelta

import pytest

from tsdb_service.core.buckets import choose_width
from tsdb_service.usecases import enums, sites

PREFIX = "/grafana/simplejson"
MOWER = sites.LAWNMOWER_ID
LAWNMOWER = {"Fiware-Service": "lawnmower", "Fiware-ServicePath": "/bosch"}
DRONE = {"Fiware-Service": "drone", "Fiware-ServicePath": "/eprosima"}
SPEED = f"{MOWER}/odom(twist.twist.linear.x)"


def _iso(ms: int) -> str:
    return datetime.fromtimestamp(ms / 1000, tz=UTC).strftime("%Y-%m-%dT%H:%M:%S.") + f"{ms % 1000:03d}Z"


@pytest.fixture(scope="module")
def span(grafana_server):
    return grafana_server.range_ms


def _classic_query(span, targets, max_points=500, **extra) -> dict:
    start, end = span
    return {
        "timezone": "browser",
        "panelId": 2,
        "dashboardId": 1,
        "range": {"from": _iso(start), "to": _iso(end), "raw": {"from": "now-6h", "to": "now"}},
        "rangeRaw": {"from": "now-6h", "to": "now"},
        "interval": "20s",
        "intervalMs": 20000,
        "maxDataPoints": max_points,
        "format": "json",
        "targets": targets,
        "scopedVars": {
            "__interval": {"text": "20s", "value": "20s"},
            "__interval_ms": {"text": "20000", "value": 20000},
        },
        "adhocFilters": [],
        **extra,
    }


def _simpod_query(span, targets, **extra) -> dict:
    start, end = span
    body = _classic_query(span, targets, **extra)
    body.update(
        {
            "app": "dashboard",
            "requestId": "SQR108",
            "dashboardUID": "abc",
            "panelPluginId": "timeseries",
            "startTime": end,
            "timeInfo": "",
            "liveStreaming": False,
            "filters": [],
            "range": {"from": _iso(start), "to": _iso(end), "raw": {"from": "now-6h", "to": "now"}},
        }
    )
    return body


def _simpod_target(target: str, ref: str = "A", **payload) -> dict:
    return {
        "refId": ref,
        "datasource": {"type": "simpod-json-datasource", "uid": "P1809F7CD0C75ACF3"},
        "editorMode": "code",
        "target": target,
        "payload": payload,
        "key": "Q-1",
    }


def _post(http, path: str, body, headers=LAWNMOWER, status: int = 200):
    response = http.post(PREFIX + path, json=body, headers=headers)
    assert response.status_code == status, f"{path}: {response.status_code} {response.text[:300]}"
    return response.json()


def test_test_connection(grafana_http):
    for path in (PREFIX, PREFIX + "/"):
        response = grafana_http.get(path, headers=LAWNMOWER)
        assert response.status_code == 200 and response.json()["tenant"] == "lawnmower"


# --- classic SimpleJSON ---------------------------------------------------------------------------------


def test_search_lists_metrics_and_variable_values(grafana_http):
    metrics = _post(grafana_http, "/search", {"target": ""})
    assert f"{MOWER}/odom" in metrics and f"{MOWER}/navigationState" in metrics
    assert _post(grafana_http, "/search", {"type": "timeserie", "target": "perimeter"}) == [
        f"{MOWER}/perimeterLeft",
        f"{MOWER}/perimeterRight",
    ]
    assert _post(grafana_http, "/search", {"target": "entities"}) == [MOWER]
    sensors = _post(grafana_http, "/search", {"target": f"entities:{sites.SENSOR_TYPE}"}, headers=DRONE)
    assert sensors == list(sites.SENSOR_IDS)
    assert _post(grafana_http, "/search", {"target": "types"}, headers=DRONE) == ["ROS2System", "RemoteSensor"]
    assert "odom" in _post(grafana_http, "/search", {"target": f"attrs:{MOWER}"})


def test_timeserie_target_downsampled_to_max_data_points(grafana_http, span):
    body = _classic_query(span, [{"target": SPEED, "refId": "A", "type": "timeserie", "hide": False}], max_points=50)
    response = grafana_http.post(PREFIX + "/query", json=body, headers=LAWNMOWER)
    assert response.status_code == 200, response.text
    (series,) = response.json()
    assert series["target"].endswith("odom(twist.twist.linear.x)")
    points = series["datapoints"]
    # 50 round buckets (at least intervalMs) span the whole requested range; the mower's 20 minutes fill some
    width = choose_width(timedelta(milliseconds=span[1] - span[0]), 50, timedelta(milliseconds=20000))
    assert response.headers["X-Tsdb-Bucket-Ms"] == str(width // timedelta(milliseconds=1))
    assert series["meta"]["custom"]["bucketMs"] == width // timedelta(milliseconds=1)
    assert all(t % (width // timedelta(milliseconds=1)) == 0 for _, t in series["datapoints"][1:])
    assert 3 <= len(points) <= 50
    times = [t for _, t in points]
    assert times == sorted(times) and all(isinstance(t, int) for t in times)
    assert all(isinstance(v, float) and -0.3 < v < 0.6 for v, _ in points), "averages of the speed"


def test_table_target(grafana_http, span):
    body = _classic_query(span, [{"target": f"{MOWER}/navigationState(data)", "refId": "B", "type": "table"}])
    (table,) = _post(grafana_http, "/query", body)
    assert table["type"] == "table"
    assert [c["text"] for c in table["columns"]] == ["Time", "entity", "navigationState(data)"]
    assert [c["type"] for c in table["columns"]] == ["time", "string", "number"]
    assert table["rows"] and all(len(r) == 3 and r[1] == MOWER for r in table["rows"])
    assert {r[2] for r in table["rows"]} <= set(enums.LAWNMOWER_NAVIGATION_STATE), (
        "states are kept (last), not averaged"
    )


def test_hidden_and_empty_targets_are_skipped(grafana_http, span):
    body = _classic_query(span, [{"target": SPEED, "refId": "A", "hide": True}, {"refId": "B"}])
    assert _post(grafana_http, "/query", body) == []


def test_classic_annotations(grafana_http, span):
    start, end = span
    body = {
        "range": {"from": _iso(start), "to": _iso(end)},
        "rangeRaw": {"from": "now-1h", "to": "now"},
        "annotation": {
            "name": "perimeter",
            "datasource": "tsdb",
            "iconColor": "rgba(255, 96, 96, 1)",
            "enable": True,
            "query": f"{MOWER}/perimeterLeft(data)=true",
        },
        "variables": [],
    }
    events = _post(grafana_http, "/annotations", body)
    assert events
    for event in events:
        assert event["annotation"]["name"] == "perimeter"
        assert isinstance(event["time"], int) and event["timeEnd"] >= event["time"]
        assert event["isRegion"] == (event["timeEnd"] > event["time"])
        assert event["title"] and event["text"] and event["tags"] == ["Lawnmower01", "perimeterLeft(data)"]
    assert _post(grafana_http, "/annotations", {**body, "annotation": {"query": ""}}) == []


def test_ad_hoc_filters(grafana_http, span):
    assert _post(grafana_http, "/tag-keys", {}) == [
        {"type": "string", "text": "entity"},
        {"type": "string", "text": "type"},
        {"type": "string", "text": "name"},
    ]
    names = _post(grafana_http, "/tag-values", {"key": "name"}, headers=DRONE)
    assert [n["text"] for n in names] == ["Drone01", *(f"Sensor0{i}" for i in range(1, 9))]
    target = {"target": "*/temperature", "refId": "A", "type": "timeserie"}
    every = _post(grafana_http, "/query", _classic_query(span, [target]), headers=DRONE)
    assert len(every) == 8
    only = _post(
        grafana_http,
        "/query",
        _classic_query(span, [target], adhocFilters=[{"key": "name", "operator": "=~", "value": "Sensor0[12]$"}]),
        headers=DRONE,
    )
    assert [s["target"] for s in only] == ["Sensor01 temperature", "Sensor02 temperature"]


# --- simPod JSON -------------------------------------------------------------------------------------------


def test_simpod_query_with_payload_and_grafanas_whole_request(grafana_http, span):
    body = _simpod_query(
        span,
        [
            _simpod_target(f"{MOWER}/odom", "A", path="twist.twist.angular.z", alias="yaw_rate"),
            _simpod_target(f"{MOWER}/perimeterRight(data)", "B", format="table"),
        ],
        max_points=5000,
    )
    series, table = _post(grafana_http, "/query", body)
    assert series["target"] == "yaw_rate" and series["refId"] == "A" and series["datapoints"]
    assert table["type"] == "table" and table["columns"][2] == {"text": "perimeterRight(data)", "type": "boolean"}
    assert any(row[2] is True for row in table["rows"])


def test_simpod_data_frames(grafana_http, span):
    body = _simpod_query(span, [_simpod_target("*/humidity", "C", format="dataframe", type=sites.SENSOR_TYPE)])
    frames = _post(grafana_http, "/query", body, headers=DRONE)
    assert len(frames) == 8
    for frame in frames:
        assert frame["refId"] == "C"
        time_field, value_field = frame["fields"]
        assert time_field["name"] == "time" and time_field["type"] == "time"
        assert value_field["type"] == "number" and value_field["labels"]["entity"].startswith("urn:ngsiv2:RemoteSensor")
        assert len(time_field["values"]) == len(value_field["values"]) > 0


def test_simpod_annotations_through_query(grafana_http, span):
    body = _simpod_query(span, [_simpod_target(f"{MOWER}/perimeterRight(data)", "A", format="annotations")])
    (frame,) = _post(grafana_http, "/query", body)
    names = [f["name"] for f in frame["fields"]]
    assert names == ["time", "timeEnd", "title", "text", "tags"]
    assert frame["fields"][0]["values"], "the mower detects the wire on its right"


def test_simpod_variable(grafana_http, span):
    start, end = span
    rng = {"from": _iso(start), "to": _iso(end), "raw": {"from": "now-6h", "to": "now"}}
    values = _post(
        grafana_http, "/variable", {"payload": {"target": "entities:RemoteSensor"}, "range": rng}, headers=DRONE
    )
    assert values[0] == {"__text": "Sensor01", "__value": "urn:ngsiv2:RemoteSensor:Sensor01"} and len(values) == 8
    as_text = _post(grafana_http, "/variable", {"payload": "types", "range": rng}, headers=DRONE)
    assert [v["__value"] for v in as_text] == ["ROS2System", "RemoteSensor"]


def test_simpod_metrics_and_payload_options(grafana_http):
    metrics = _post(grafana_http, "/metrics", {})
    odom = next(m for m in metrics if m["value"] == f"{MOWER}/odom")
    assert odom["label"] == "Lawnmower01 odom"
    assert {p["name"] for p in odom["payloads"]} == {"path", "agg", "fill", "format", "alias"}
    first = _post(grafana_http, "/metrics", {"metric": f"{MOWER}/odom", "payload": {"agg": "avg"}})
    assert first[0]["value"] == f"{MOWER}/odom"
    paths = _post(grafana_http, "/metric-payload-options", {"metric": f"{MOWER}/odom", "payload": {}, "name": "path"})
    values = [p["value"] for p in paths]
    assert "twist.twist.linear.x" in values and "pose.pose.position.x" in values and "pose.covariance[0]" in values
    aggs = _post(grafana_http, "/metric-payload-options", {"metric": "", "payload": {}, "name": "agg"})
    assert {"label": "avg", "value": "avg"} in aggs
    assert _post(grafana_http, "/metric-payload-options", {"metric": "x", "payload": {}, "name": "zzz"}) == []


# --- errors -------------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("path", "body"),
    [
        ("/query", {"targets": [{"target": "no-slash", "refId": "A"}]}),
        ("/query", {"targets": [{"target": f"{MOWER}/odom(", "refId": "A"}]}),
        ("/query", {"targets": [{"target": SPEED, "refId": "A", "payload": {"agg": "median"}}]}),
        ("/query", {"targets": [{"target": SPEED, "refId": "A", "payload": {"format": "xml"}}]}),
        ("/query", {"targets": "A", "range": {"from": "x"}}),
        ("/query", {"targets": [], "range": {"from": "yesterday", "to": "now"}}),
        (
            "/query",
            {"targets": [{"target": SPEED}], "range": {"from": "2024-02-01T00:00:00Z", "to": "2024-01-01T00:00:00Z"}},
        ),
        ("/query", {"targets": [{"target": SPEED}], "maxDataPoints": -3}),
        ("/query", {"targets": [{"target": SPEED, "payload": {"idPattern": "("}}]}),
        (
            "/query",
            {"targets": [{"target": SPEED}], "adhocFilters": [{"key": "entity", "operator": "=~", "value": "("}]},
        ),
    ],
)
def test_bad_requests_are_400_in_the_ngsi_shape(grafana_http, path, body):
    doc = _post(grafana_http, path, body, status=400)
    assert set(doc) == {"error", "description"} and doc["description"]


@pytest.mark.parametrize("body", [None, [], "text", 42, {"targets": None}, {"range": None}, {"annotation": 3}])
@pytest.mark.parametrize(
    "path",
    [
        "/search",
        "/query",
        "/annotations",
        "/variable",
        "/metrics",
        "/metric-payload-options",
        "/tag-keys",
        "/tag-values",
    ],
)
def test_odd_bodies_are_read_as_an_empty_request(grafana_http, path, body):
    """Grafana's plugins post what they have: a body that is not an object, or whose
    keys hold the wrong kind of value, is answered as the empty request ``{}`` is."""
    response = grafana_http.post(PREFIX + path, json=body, headers=LAWNMOWER)
    assert response.status_code == 200, f"{path} {body!r}: {response.status_code} {response.text[:200]}"
    assert response.json() == _post(grafana_http, path, {}), f"{path} {body!r}"


def test_malformed_json_and_bad_tenant_are_400(grafana_http):
    response = grafana_http.post(
        PREFIX + "/query", content=b"{not json", headers={**LAWNMOWER, "Content-Type": "application/json"}
    )
    assert response.status_code == 400 and response.json()["error"] == "BadRequest"
    response = grafana_http.post(PREFIX + "/search", json={}, headers={"Fiware-Service": "bad tenant!"})
    assert response.status_code == 400 and set(response.json()) == {"error", "description"}
