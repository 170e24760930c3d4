"""Contract: every panel of the drone dashboard that reads the NGSI-LD
temporal API (``dashboards/drone-ld.json``) shows data.

As ``test_grafana_contract`` does for the other dashboards: the service
runs on a real HTTP port loaded with the seeded drone burst
(``tests/grafana_fixtures``); each target's request is sent as Grafana's
Infinity datasource would send it (the datasource's URL and headers from
``dashboards/provisioning/datasources.yaml``, ``${__from:date:iso}`` /
``${__to:date:iso}`` interpolated with the dashboard's range). Then the
Infinity *backend* parser's work is redone here for the subset of gjson
paths the dashboard uses (dotted keys and array indexes): the root
selector picks the rows, each column's selector a value. Every column must
be present, non-null somewhere and of its declared type, and the fields
each panel reads must exist.
"""

from __future__ import annotations

import re
from datetime import UTC, datetime
from urllib.parse import urljoin

import pytest
import yaml

from tests.grafana_fixtures import ROOT, panels_of
from tsdb_service.faces.grafana import dashboards
from tsdb_service.usecases import enums, sites

NAME = "drone-ld"
_MISSING = object()


def select(doc, path: str):
    """A gjson path of dotted keys and array indexes (``a.values.0.1``);
    ``""`` is the document. A missing step gives ``_MISSING``."""
    if path == "":
        return doc
    for step in path.split("."):
        if isinstance(doc, list) and step.isdigit():
            index = int(step)
            doc = doc[index] if index < len(doc) else _MISSING
        elif isinstance(doc, dict):
            doc = doc.get(step, _MISSING)
        else:
            return _MISSING
        if doc is _MISSING:
            return _MISSING
    return doc


def frame(body, target: dict) -> list[dict]:
    """Rows as the backend parser makes them: the root's array items (one
    row for an object), each column read with its selector (null when missing)."""
    root = select(body, target["root_selector"])
    assert root is not _MISSING, f"root selector {target['root_selector']!r} selects nothing"
    items = root if isinstance(root, list) else [root]
    rows = []
    for item in items:
        row = {}
        for column in target["columns"]:
            value = select(item, column["selector"])
            row[column["text"]] = None if value is _MISSING else value
        rows.append(row)
    return rows


def test_the_path_subset():
    body = [{"id": "a", "t": {"values": [[{"data": 1.5}, "2024-01-01T00:00:00Z"]]}}]
    assert select(body, "0.t.values.0.0.data") == 1.5
    assert select(body, "0.t.values.1") is _MISSING and select(body, "0.x") is _MISSING
    target = {
        "root_selector": "0.t.values",
        "columns": [
            {"selector": "1", "text": "time", "type": "timestamp"},
            {"selector": "0.nope", "text": "v", "type": "number"},
        ],
    }
    assert frame(body, target) == [{"time": "2024-01-01T00:00:00Z", "v": None}]


def _datasource(uid: str) -> dict:
    doc = yaml.safe_load((ROOT / "dashboards" / "provisioning" / "datasources.yaml").read_text())
    ds = next(d for d in doc["datasources"] if d["uid"] == uid)
    headers = {
        ds["jsonData"][f"httpHeaderName{i}"]: ds["secureJsonData"][f"httpHeaderValue{i}"]
        for i in range(1, 10)
        if f"httpHeaderName{i}" in ds["jsonData"]
    }
    return {"headers": headers}


def _iso(ms: int) -> str:
    return datetime.fromtimestamp(ms / 1000, tz=UTC).isoformat(timespec="milliseconds").replace("+00:00", "Z")


def _interpolate(value: str, start_ms: int, end_ms: int) -> str:
    value = value.replace("${__from:date:iso}", _iso(start_ms)).replace("${__to:date:iso}", _iso(end_ms))
    assert "$" not in value, f"uninterpolated Grafana variable in {value!r}"
    return value


def _run(http, server, target: dict, time_range: tuple[int, int]) -> list[dict]:
    assert target["type"] == "json" and target["source"] == "url" and target["parser"] == "backend"
    assert target["url"].startswith("/ngsi-ld/v1/temporal/entities")
    params = [(p["key"], _interpolate(p["value"], *time_range)) for p in target["url_options"]["params"]]
    response = http.get(
        urljoin(server.url, target["url"]), params=params, headers=_datasource(target["datasource"]["uid"])["headers"]
    )
    assert response.status_code == 200, f"{target['url']} {params}: {response.status_code} {response.text[:300]}"
    return frame(response.json(), target)


def _is(kind: str, value) -> bool:
    if kind == "number":
        return type(value) in (int, float)
    if kind == "string":
        return type(value) is str
    assert kind == "timestamp", kind
    return type(value) is str and datetime.fromisoformat(value.replace("Z", "+00:00")) is not None


def _views(server) -> list[tuple[str, dict, dict, tuple[int, int]]]:
    doc = dashboards.build(NAME)
    now = server.fed_at_ms + 1000
    match = re.fullmatch(r"now-(\d+)h", doc["time"]["from"])
    assert match and doc["time"]["to"] == "now"
    time_range = (now - int(match.group(1)) * 3_600_000, now)
    return [
        (f"panel {p['id']} {p['title']!r} target {t['refId']}", p, t, time_range)
        for p in panels_of(doc)
        if p["type"] != "row"
        for t in p["targets"]
    ]


def _check(where: str, panel: dict, target: dict, rows: list[dict]) -> None:
    assert rows, f"{where}: no rows: the panel would show 'No data'"
    declared = {c["text"]: c["type"] for c in target["columns"]}
    for name, kind in declared.items():
        present = [row[name] for row in rows if row[name] is not None]
        assert present, f"{where}: column {name!r} is missing or always null"
        wrong = [v for v in present if not _is(kind, v)]
        assert not wrong, f"{where}: column {name!r} should be {kind}, got {wrong[:3]}"
    kind, options = panel["type"], panel.get("options", {})
    if kind in ("timeseries", "state-timeline"):
        assert "timestamp" in declared.values() and "number" in declared.values(), where
    if kind == "barchart":
        assert declared.get(options["xField"]) == "string", where
    if kind == "geomap":
        for layer in options["layers"]:
            location = layer["location"]
            assert declared.get(location["latitude"]) == "number" and declared.get(location["longitude"]) == "number"


def test_every_panel_reads_the_temporal_api_and_shows_its_fields(grafana_server, grafana_http):
    views = _views(grafana_server)
    assert len({where.split(" target")[0] for where, *_ in views}) >= 6
    for where, panel, target, time_range in views:
        _check(where, panel, target, _run(grafana_http, grafana_server, target, time_range))


def test_what_the_panels_show(grafana_server, grafana_http):
    """The numbers are the drone's: states are known codes, the sensors are the 8 sites, positions near home."""
    views = {panel["title"]: (target, time_range) for _, panel, target, time_range in _views(grafana_server)}

    def rows(title_start: str) -> list[dict]:
        target, time_range = next(v for title, v in views.items() if title.startswith(title_start))
        return _run(grafana_http, grafana_server, target, time_range)

    states = {row["mission"] for row in rows("Mission state")}
    assert len(states) >= 3 and states <= set(enums.DRONE_MISSION_STATE)
    averages = rows("Average measures")
    assert sorted(row["id"] for row in averages) == sorted(sites.SENSOR_IDS)
    assert all(0 <= row["humidity"] <= 100 and 0 < row["temperature"] < 45 for row in averages)
    latest = rows("Latest sensor readings")
    assert len(latest) == 8 and all(row["time"] for row in latest)
    track = rows("Where the drone flew")
    assert len(track) > 100
    assert all(
        abs(row["lat"] - sites.DRONE_HOME[0]) < 0.05 and abs(row["lon"] - sites.DRONE_HOME[1]) < 0.05 for row in track
    )


def test_the_contract_catches_a_wrong_selector(grafana_server, grafana_http):
    where, panel, target, time_range = next(v for v in _views(grafana_server) if v[1]["type"] == "timeseries")
    broken = dict(target, columns=[dict(c, selector=c["selector"].replace("data", "dta")) for c in target["columns"]])
    with pytest.raises(AssertionError, match="missing or always null"):
        _check(where, panel, broken, _run(grafana_http, grafana_server, broken, time_range))
