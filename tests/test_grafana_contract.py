"""Contract: every panel of every shipped dashboard shows data.

The service runs on a real HTTP port with the suite's backend, loaded with a
seeded burst of the three use-case simulators (``tests/grafana_fixtures``).
Each dashboard is then "opened" the way Grafana would at the moment the feed
ended: its own time range (``now-30m`` ...), each panel's ``timeFrom``, the
datasource's URL and custom headers taken from
``dashboards/provisioning/datasources.yaml``, Grafana's ``${__from}`` /
``${__to}`` / ``${__interval_ms}`` interpolated into the Infinity query
parameters. For every target (and every annotation query):

* the request succeeds and returns rows: a panel that would show "No data" fails;
* every column the target declares is there, non-null somewhere, and of the
  declared Infinity type (number, boolean, string, timestamp);
* the fields the panel itself reads exist: a stat's or gauge's
  ``reduceOptions.fields``, a bar chart's ``xField``, a geomap layer's
  latitude / longitude / text / colour fields, a time field and a value for
  time series and state timelines, annotation fields;
* values shown through value mappings are codes the mapping names.
"""

from __future__ import annotations

import itertools
import re
from datetime import datetime
from urllib.parse import urljoin

import httpx
import pytest
import yaml

from tests.grafana_fixtures import ROOT
from tests.grafana_fixtures import panels_of as _panels
from tests.support.golden_http import GoldenFile, GoldenHttp
from tsdb_service.faces.grafana import dashboards
from tsdb_service.usecases import enums

USE_CASES = list(dashboards.BUILDERS)
_UNITS_MS = {"s": 1000, "m": 60_000, "h": 3_600_000, "d": 86_400_000}


def _relative(text: str, now_ms: int) -> int:
    if text == "now":
        return now_ms
    match = re.fullmatch(r"now-(\d+)([smhd])", text)
    assert match, f"unsupported relative time {text!r}"
    return now_ms - int(match.group(1)) * _UNITS_MS[match.group(2)]


def _datasources() -> dict[str, dict]:
    doc = yaml.safe_load((ROOT / "dashboards" / "provisioning" / "datasources.yaml").read_text())
    out = {}
    for ds in doc["datasources"]:
        json_data, secure = ds.get("jsonData", {}), ds.get("secureJsonData", {})
        headers = {
            json_data[f"httpHeaderName{i}"]: secure[f"httpHeaderValue{i}"]
            for i in range(1, 10)
            if f"httpHeaderName{i}" in json_data
        }
        out[ds["uid"]] = {"url": ds["url"], "headers": headers, "type": ds["type"]}
    return out


def _interpolate(value: str, variables: dict[str, str]) -> str:
    for name, replacement in variables.items():
        value = value.replace("${" + name + "}", replacement).replace("$" + name, replacement)
    assert "$" not in value, f"uninterpolated Grafana variable in {value!r}"
    return value


def _run(http, server, target: dict, time_range: tuple[int, int], max_points: float | None) -> list[dict]:
    """Execute an Infinity target as Grafana would, against the test server."""
    ds = _datasources()[target["datasource"]["uid"]]
    assert target["type"] == "json" and target["source"] == "url" and target["parser"] == "backend"
    assert target["url_options"]["method"] == "GET"
    start, end = time_range
    interval = max(1, (end - start) // int(max_points or 1000))
    variables = {"__from": str(start), "__to": str(end), "__interval_ms": str(interval)}
    params = [(p["key"], _interpolate(p["value"], variables)) for p in target["url_options"]["params"]]
    # The datasource URL prefixes the query's relative URL; here it is the test server.
    assert target["url"].startswith("/")
    url = urljoin(server.url, target["url"])
    response = http.get(url, params=params, headers=ds["headers"])
    assert response.status_code == 200, f"{target['url']} {params}: {response.status_code} {response.text[:300]}"
    rows = response.json()
    assert isinstance(rows, list)
    return rows


def _is(kind: str, value) -> bool:
    if kind == "number":
        return type(value) in (int, float)
    if kind == "boolean":
        return type(value) is bool
    if kind == "string":
        return type(value) is str
    if kind == "timestamp":
        if type(value) is not str:
            return False
        try:
            datetime.fromisoformat(value.replace("Z", "+00:00"))
        except ValueError:
            return False
        return True
    raise AssertionError(f"unknown Infinity column type {kind!r}")


def _check_columns(where: str, target: dict, rows: list[dict]) -> dict[str, str]:
    assert rows, f"{where}: the query returned no rows: the panel would show 'No data'"
    declared = {c["selector"]: c["type"] for c in target["columns"]}
    assert declared, f"{where}: the target declares no columns"
    for col in target["columns"]:
        assert col["text"] == col["selector"], f"{where}: column {col} renames its field"
    for name, kind in declared.items():
        present = [row[name] for row in rows if row.get(name) is not None]
        assert present, f"{where}: column {name!r} is missing or always null"
        wrong = [v for v in present if not _is(kind, v)]
        assert not wrong, f"{where}: column {name!r} should be {kind}, got {wrong[:3]}"
    return declared


def _mapping_keys(panel: dict) -> set[str] | None:
    mappings = panel.get("fieldConfig", {}).get("defaults", {}).get("mappings")
    if not mappings:
        return None
    keys = set()
    for mapping in mappings:
        if mapping["type"] == "value":
            keys |= set(mapping["options"])
    return keys


def _as_key(value) -> str:
    return str(value).lower() if isinstance(value, bool) else str(value)


def _check_panel_fields(where: str, panel: dict, declared: dict[str, str], rows: list[dict]) -> None:
    kind = panel["type"]
    options = panel.get("options", {})
    names = set(declared)
    values = [n for n, k in declared.items() if k in ("number", "boolean")]
    if kind in ("stat", "gauge"):
        pattern = options["reduceOptions"]["fields"]
        regex = re.compile(pattern.strip("/"))
        shown = [n for n in names if regex.search(n)]
        assert shown, f"{where}: reduceOptions.fields {pattern!r} matches none of {sorted(names)}"
    if kind in ("timeseries", "state-timeline"):
        assert "timestamp" in declared.values(), f"{where}: no time field"
        assert values, f"{where}: no numeric or boolean field to draw"
    if kind == "barchart":
        assert options["xField"] in names, f"{where}: xField {options['xField']!r} not in {sorted(names)}"
        assert [n for n, k in declared.items() if k == "number" and n != options["xField"]], f"{where}: no bars"
    if kind == "geomap":
        for layer in options["layers"]:
            location = layer["location"]
            assert location["mode"] == "coords"
            for field in (location["latitude"], location["longitude"]):
                assert declared.get(field) == "number", f"{where}: layer {layer['name']!r} reads {field!r}"
            style = layer.get("config", {}).get("style", {})
            for dim in ("text", "color", "size"):
                field = style.get(dim, {}).get("field")
                if field:
                    assert field in names, f"{where}: layer style {dim} reads missing field {field!r}"
    keys = _mapping_keys(panel)
    if keys is not None and kind in ("stat", "state-timeline"):
        mapped = [n for n in values if n in names]
        for name in mapped:
            seen = {_as_key(row[name]) for row in rows if row.get(name) is not None}
            assert seen <= keys, f"{where}: values {sorted(seen - keys)} of {name!r} have no value mapping"
            if kind == "state-timeline" and declared[name] == "number":
                assert len(seen) >= 2, f"{where}: {name!r} never changes state: {seen}"


@pytest.fixture(scope="module")
def views(grafana_server):
    """Every (where, panel, target, range, max points) a dashboard would query."""
    now = grafana_server.fed_at_ms + 1000
    out = []
    for name in USE_CASES:
        doc = dashboards.build(name)
        dash_range = (_relative(doc["time"]["from"], now), _relative(doc["time"]["to"], now))
        for panel in _panels(doc):
            if panel["type"] == "row":
                continue
            panel_range = dash_range
            if panel.get("timeFrom"):
                panel_range = (_relative(f"now-{panel['timeFrom']}", now), now)
            for target in panel["targets"]:
                where = f"{name} panel {panel['id']} {panel['title']!r} target {target['refId']}"
                out.append((where, panel, target, panel_range, panel.get("maxDataPoints")))
        for item in doc["annotations"].get("list", []):
            out.append((f"{name} annotation {item['name']!r}", None, item["target"], dash_range, None))
    return out


def test_every_dashboard_has_panels_and_annotations(views):
    for name in USE_CASES:
        assert sum(1 for where, *_ in views if where.startswith(name + " panel")) >= 5, name
    assert any(" annotation " in where for where, *_ in views)


@pytest.mark.parametrize("use_case", USE_CASES)
def test_every_panel_query_returns_the_fields_it_reads(use_case, views, grafana_server, grafana_http):
    checked = 0
    for where, panel, target, time_range, max_points in views:
        if not where.startswith(use_case + " "):
            continue
        rows = _run(grafana_http, grafana_server, target, time_range, max_points)
        declared = _check_columns(where, target, rows)
        if panel is None:  # an annotation query
            assert {"time", "timeEnd", "title", "text"} <= set(declared), f"{where}: not an annotation frame"
            assert all(row["time"] <= row["timeEnd"] for row in rows), f"{where}: an event ends before it starts"
        else:
            _check_panel_fields(where, panel, declared, rows)
            if max_points:
                per_entity: dict[str, int] = {}
                for row in rows:
                    per_entity[row.get("entity", "")] = per_entity.get(row.get("entity", ""), 0) + 1
                assert max(per_entity.values()) <= max_points, f"{where}: more rows than maxDataPoints"
        checked += 1
    assert checked >= 6, f"{use_case}: only {checked} queries"


def test_the_drone_map_shows_the_drone_and_the_8_sensors_with_readings(views, grafana_server, grafana_http):
    where, _panel, target, time_range, max_points = next(
        v for v in views if v[1] and v[1]["type"] == "geomap" and v[1]["options"]["layers"][0]["type"] == "markers"
    )
    rows = _run(grafana_http, grafana_server, target, time_range, max_points)
    by_type: dict[str, list] = {}
    for row in rows:
        by_type.setdefault(row["type"], []).append(row)
    assert len(by_type["ROS2System"]) == 1 and len(by_type["RemoteSensor"]) == 8, where
    assert all(row["temperature"] is not None and row["humidity"] is not None for row in by_type["RemoteSensor"])


def test_the_heatmap_has_many_drone_positions(views, grafana_server, grafana_http):
    where, _panel, target, time_range, max_points = next(
        v for v in views if v[1] and v[1]["type"] == "geomap" and v[1]["options"]["layers"][0]["type"] == "heatmap"
    )
    rows = _run(grafana_http, grafana_server, target, time_range, max_points)
    assert len(rows) > 500 and {row["entity"] for row in rows} == {"urn:ngsiv2:ROS2System:Drone01"}, where


def test_the_contract_catches_a_panel_without_data(views, grafana_server, grafana_http):
    """A typo in a value path, or the wrong tenant, leaves a panel empty: the check fails."""
    where, _panel, target, time_range, max_points = next(v for v in views if v[1] and v[1]["type"] == "stat")
    broken = dict(
        target,
        url_options=dict(
            target["url_options"],
            params=[
                {"key": p["key"], "value": p["value"].replace("(", "(nope.") if p["key"] == "attrs" else p["value"]}
                for p in target["url_options"]["params"]
            ],
        ),
    )
    with pytest.raises(AssertionError, match=r"No data|missing or always null"):
        _check_columns(where, broken, _run(grafana_http, grafana_server, broken, time_range, max_points))
    other_tenant = dict(target, datasource={**target["datasource"], "uid": "tsdb-drone"})
    if target["datasource"]["uid"] != "tsdb-drone":
        with pytest.raises(AssertionError, match="No data"):
            _check_columns(where, other_tenant, _run(grafana_http, grafana_server, other_tenant, time_range, None))


# --- the Infinity API itself ------------------------------------------------------------------------------

API = "/grafana/infinity"
LAWNMOWER = {"Fiware-Service": "lawnmower", "Fiware-ServicePath": "/bosch"}
DRONE_HEADERS = {"Fiware-Service": "drone", "Fiware-ServicePath": "/eprosima"}
MOWER = "urn:ngsiv2:ROS2System:Lawnmower01"


def _get(http, path, params, headers=LAWNMOWER, status=200):
    response = http.get(API + path, params=params, headers=headers)
    assert response.status_code == status, f"{path} {params}: {response.status_code} {response.text[:300]}"
    return response.json()


def test_series_downsamples_avg_for_numbers_and_last_for_states(grafana_server, grafana_http):
    start, end = grafana_server.range_ms
    cols = "speed=odom(twist.twist.linear.x),state=navigationState(data)"
    raw = _get(grafana_http, "/series", {"id": MOWER, "attrs": cols, "from": start, "to": end, "max_points": 100000})
    assert len(raw) > 1000 and all(set(r) == {"time", "entity", "speed", "state"} for r in raw)
    few = _get(
        grafana_http,
        "/series",
        {"id": MOWER, "attrs": cols, "from": start, "to": end, "max_points": 20, "interval_ms": 1000},
    )
    assert 2 <= len(few) <= 20
    codes = set(enums.LAWNMOWER_NAVIGATION_STATE)
    assert all(row["state"] in codes for row in few), "states are the last code of each bucket, not averages"
    assert any(row["speed"] not in {r["speed"] for r in raw} for row in few), "speeds are bucket averages"
    mean = sum(r["speed"] for r in raw) / len(raw)
    assert min(r["speed"] for r in few) <= mean <= max(r["speed"] for r in few)
    wide = _get(
        grafana_http,
        "/series",
        {"type": "RemoteSensor", "attrs": "t=temperature", "layout": "wide", "from": _iso(start), "to": _iso(end)},
        headers=DRONE_HEADERS,
    )
    assert set(wide[0]) == {"time", *(f"Sensor0{i} t" for i in range(1, 9))}


def _iso(ms: int) -> str:
    return datetime.fromtimestamp(ms / 1000).astimezone().isoformat()


def test_tenant_as_query_parameters(grafana_http):
    by_headers = _get(grafana_http, "/latest", {"attrs": "s=navigationState(data)"})
    by_params = _get(
        grafana_http,
        "/latest",
        {"attrs": "s=navigationState(data)", "service": "lawnmower", "servicepath": "/bosch"},
        headers={},
    )
    assert by_headers == by_params and len(by_params) == 1
    assert _get(grafana_http, "/latest", {"attrs": "s=navigationState(data)", "servicepath": "/piap"}) == []


def test_states_are_changes_only(grafana_server, grafana_http):
    start, end = grafana_server.range_ms
    rows = _get(grafana_http, "/states", {"id": MOWER, "attrs": "s=navigationState(data)", "from": start, "to": end})
    codes = [r["s"] for r in rows]
    assert all(a != b for a, b in itertools.pairwise(codes[:-1])), "consecutive rows differ"
    assert len(rows) < 200


def test_events_with_equals_and_positions_with_a_geo_query(grafana_server, grafana_http):
    start, end = grafana_server.range_ms
    reading = _get(
        grafana_http,
        "/events",
        {
            "id": "urn:ngsiv2:ROS2System:Drone01",
            "attrs": "m=missionState(data)",
            "equals": "3",
            "from": start,
            "to": end,
        },
        headers=DRONE_HEADERS,
    )
    assert len(reading) >= 10 and all(r["timeEnd"] >= r["time"] for r in reading)
    field = "40.6050,-3.6905;40.6110,-3.6812"  # the sensor field (lat,lon corners)
    inside = _get(
        grafana_http,
        "/positions",
        {"georel": "coveredBy", "geometry": "box", "coords": field, "from": start, "to": end},
        headers=DRONE_HEADERS,
    )
    assert inside and all(40.6050 <= r["lat"] <= 40.6110 and -3.6905 <= r["lon"] <= -3.6812 for r in inside)
    latest = _get(
        grafana_http,
        "/positions",
        {"latest": "true", "georel": "coveredBy", "geometry": "box", "coords": field},
        headers=DRONE_HEADERS,
    )
    assert {r["name"] for r in latest} >= {f"Sensor0{i}" for i in range(1, 9)}
    near = _get(
        grafana_http,
        "/positions",
        {"latest": "true", "georel": "near;maxDistance:50", "geometry": "point", "coords": "40.603,-3.693"},
        headers=DRONE_HEADERS,
    )
    assert all(r["name"] == "Drone01" for r in near)


def test_aggregate_per_entity(grafana_server, grafana_http):
    counts = _get(
        grafana_http,
        "/aggregate",
        {"type": "RemoteSensor", "attrs": "n=temperature", "method": "count"},
        headers=DRONE_HEADERS,
    )
    assert len(counts) == 8 and sum(r["n"] for r in counts) >= 8 + 15, "installation plus one reading per visit"
    hourly = _get(
        grafana_http,
        "/aggregate",
        {"type": "RemoteSensor", "attrs": "t=temperature", "period": "hour"},
        headers=DRONE_HEADERS,
    )
    assert all(row["time"].endswith(":00:00.000Z") for row in hourly)


@pytest.mark.parametrize(
    ("path", "params"),
    [
        ("/series", {}),
        ("/series", {"attrs": "odom("}),
        ("/series", {"attrs": "a=x,a=y"}),
        ("/series", {"attrs": "time=odom"}),
        ("/series", {"attrs": "1bad=odom"}),
        ("/series", {"attrs": "odom", "from": "yesterday"}),
        ("/series", {"attrs": "odom", "from": "2024-02-01T00:00:00Z", "to": "2024-01-01T00:00:00Z"}),
        ("/series", {"attrs": "odom", "max_points": "0"}),
        ("/series", {"attrs": "odom", "max_points": "nan"}),
        ("/series", {"attrs": "odom", "agg": "median"}),
        ("/series", {"attrs": "odom", "layout": "tall"}),
        ("/series", {"attrs": "odom", "idPattern": "("}),
        ("/series", {"attrs": "odom", "from": "99999999999999999"}),
        ("/latest", {"attrs": "odom", "service": "no such tenant!"}),
        ("/latest", {"attrs": "odom", "servicepath": "bosch"}),
        ("/positions", {"latest": "maybe"}),
        ("/positions", {"georel": "near", "geometry": "point"}),
        ("/positions", {"georel": "within", "geometry": "box", "coords": "1,2;3,4"}),
        ("/positions", {"location": "location(("}),
        ("/aggregate", {"attrs": "odom", "method": "median"}),
        ("/aggregate", {"attrs": "odom", "period": "week"}),
        ("/events", {"attrs": "perimeterLeft(data)", "limit": "-1"}),
    ],
)
def test_bad_parameters_are_400_in_the_ngsi_shape(grafana_http, path, params):
    doc = _get(grafana_http, path, params, status=400)
    assert set(doc) == {"error", "description"} and doc["description"]


def test_odd_but_valid_requests_are_answered(grafana_http):
    assert _get(grafana_http, "/series", {"attrs": "nothing_here"}) == []
    assert _get(grafana_http, "/latest", {"attrs": "x=odom(no.such.path)"}) == []
    assert _get(grafana_http, "/entities", {}, headers={"Fiware-Service": "empty"}) == []
    text = _get(grafana_http, "/aggregate", {"attrs": "odom", "method": "avg"}, status=404)
    assert text["error"] == "AggrMethod cannot be applied"


def test_golden_answers_catch_a_changed_a_missing_and_an_extra_answer(tmp_path):
    """The golden check itself: a different, a missing or an extra answer fails."""

    class Answers:
        def __init__(self, *answers):
            self.answers = list(answers)

        def request(self, method, url, **kwargs):
            return httpx.Response(200, json=self.answers.pop(0))

    path = tmp_path / "g.json"
    path.write_text('{"t": [[1, 2.0000000000001], {"a": "b"}]}')
    same = GoldenHttp(Answers([1, 2.0], {"a": "b"}), GoldenFile(path, update=False), "t")
    same.get("/x"), same.post("/y")
    same.finish()
    with pytest.raises(AssertionError, match="differs"):
        GoldenHttp(Answers([1, 3]), GoldenFile(path, update=False), "t").get("/x")
    short = GoldenHttp(Answers([1, 2.0]), GoldenFile(path, update=False), "t")
    short.get("/x")
    with pytest.raises(AssertionError, match="1 answers, the golden file has 2"):
        short.finish()
    extra = GoldenHttp(Answers([1, 2.0], {"a": "b"}, []), GoldenFile(path, update=False), "t")
    extra.get("/x"), extra.get("/y")
    with pytest.raises(AssertionError, match="not in the golden file"):
        extra.get("/z")
