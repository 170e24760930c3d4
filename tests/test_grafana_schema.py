"""The shipped dashboards, checked offline.

* JSON Schema (``tests/vendor/grafana-jsonschema``, draft-07, vendored with
  its licence and provenance): the whole dashboard, each panel against
  ``Panel`` / ``RowPanel`` (readable errors), each panel's ``options`` and
  ``fieldConfig.defaults.custom`` against its panel schema. Only the quirks
  that folder's README lists are relaxed, in memory: geomap numbers typed as
  integers.
* SDK round trip: ``Dashboard.from_json`` then re-encode must give the same
  JSON (a misspelt or unknown key is lost on the way and shows up here).
* Structure: unique panel ids, every ``gridPos`` inside 24 columns without
  overlaps, datasource uids that exist in ``provisioning/datasources.yaml``,
  committed files identical to what the code builds, routes serving them.
"""

from __future__ import annotations

import copy
import json

import jsonschema
import pytest
import yaml
from grafana_foundation_sdk.cog.encoder import JSONEncoder
from grafana_foundation_sdk.models.dashboard import Dashboard

from tests.grafana_fixtures import ROOT
from tests.grafana_fixtures import panels_of as _panels
from tsdb_service.faces.grafana import dashboards
from tsdb_service.faces.grafana.dashboards import kit, service

SCHEMAS = ROOT / "tests" / "vendor" / "grafana-jsonschema"
USE_CASES = list(dashboards.BUILDERS)
ALL = list(dashboards.DASHBOARDS)  # the use cases and the service's own


@pytest.fixture(scope="module", params=ALL)
def board(request) -> tuple[str, dict]:
    return request.param, dashboards.build(request.param)


# --- JSON Schema ----------------------------------------------------------------------------------


def _load(name: str) -> dict:
    return json.loads((SCHEMAS / name).read_text())


def _relax_geomap(definitions: dict) -> dict:
    """README quirk 1: geomap view and layer numbers are typed ``integer``;
    Grafana stores floats (lat 48.8566, zoom 3.58, opacity 0.6)."""
    definitions = copy.deepcopy(definitions)
    for name, props in (
        ("MapViewConfig", ("lat", "lon", "zoom", "minZoom", "maxZoom", "padding")),
        ("MapLayerOptions", ("opacity",)),
    ):
        for prop in props:
            schema = definitions.get(name, {}).get("properties", {}).get(prop)
            if schema is not None and schema.get("type") == "integer":
                schema["type"] = "number"
    return definitions


def _validator(file: str, definition: str) -> jsonschema.Draft7Validator:
    definitions = _load(file)["definitions"]
    if file == "geomap.jsonschema.json":
        definitions = _relax_geomap(definitions)
    return jsonschema.Draft7Validator({"$ref": f"#/definitions/{definition}", "definitions": definitions})


def _errors(validator: jsonschema.Draft7Validator, doc, where: str) -> list[str]:
    return [
        f"{where}{'/' + '/'.join(map(str, e.absolute_path)) if e.absolute_path else ''}: {e.message[:300]}"
        for e in validator.iter_errors(doc)
    ]


def test_the_whole_dashboard_matches_the_schema(board):
    name, doc = board
    assert _errors(_validator("dashboard.jsonschema.json", "Dashboard"), doc, name) == []


def test_each_panel_matches_the_panel_schemas(board):
    name, doc = board
    problems = []
    for panel in _panels(doc):
        where = f"{name} panel {panel.get('id')} {panel.get('title')!r} ({panel['type']})"
        kind = "RowPanel" if panel["type"] == "row" else "Panel"
        problems += _errors(_validator("dashboard.jsonschema.json", kind), panel, where)
        if panel["type"] == "row":
            continue
        file = f"{panel['type'].replace('-', '')}.jsonschema.json"
        assert (SCHEMAS / file).exists(), f"{where}: no schema {file} for this panel type"
        problems += _errors(_validator(file, "Options"), panel.get("options", {}), where + " options")
        if "FieldConfig" in _load(file)["definitions"]:
            custom = panel.get("fieldConfig", {}).get("defaults", {}).get("custom", {})
            problems += _errors(_validator(file, "FieldConfig"), custom, where + " fieldConfig.defaults.custom")
    assert problems == []


def test_the_schema_check_catches_a_misspelt_option():
    doc = dashboards.build("lawnmower")
    stat = next(p for p in _panels(doc) if p["type"] == "stat")
    broken = dict(stat["options"], colourMode="background")
    assert _errors(_validator("stat.jsonschema.json", "Options"), broken, "stat")
    assert _errors(_validator("dashboard.jsonschema.json", "Dashboard"), {**doc, "refreshh": "5s"}, "dash")


# --- SDK round trip --------------------------------------------------------------------------------


def _round_trip(doc: dict) -> dict:
    kit.register()
    return json.loads(json.dumps(Dashboard.from_json(copy.deepcopy(doc)), cls=JSONEncoder))


def test_sdk_round_trip_gives_the_same_json(board):
    name, doc = board
    assert _round_trip(doc) == doc, f"{name}: parse → re-encode changed the dashboard"


def test_round_trip_catches_a_typo():
    doc = dashboards.build("warehouse")
    panel = next(p for p in doc["panels"] if p["type"] == "gauge")
    panel["options"]["showTresholdMarkers"] = True
    panel["targets"][0]["root_selectr"] = "rows"
    again = _round_trip(doc)
    assert again != doc
    text = json.dumps(again)
    assert "showTresholdMarkers" not in text and "root_selectr" not in text


# --- structure ------------------------------------------------------------------------------------------


def _provisioned() -> dict[str, dict]:
    doc = yaml.safe_load((ROOT / "dashboards" / "provisioning" / "datasources.yaml").read_text())
    return {ds["uid"]: ds for ds in doc["datasources"]}


def test_panel_ids_are_unique_and_every_panel_has_one(board):
    name, doc = board
    ids = [p.get("id") for p in _panels(doc)]
    assert all(isinstance(i, int) for i in ids), f"{name}: a panel without an id"
    assert len(ids) == len(set(ids)), f"{name}: duplicate panel ids {ids}"


def test_panels_fit_24_columns_and_do_not_overlap(board):
    name, doc = board
    taken: dict[tuple[int, int], int] = {}
    for panel in _panels(doc):
        pos = panel["gridPos"]
        assert pos["w"] >= 1 and pos["h"] >= 1, f"{name} panel {panel['id']}: empty gridPos {pos}"
        assert pos["x"] >= 0 and pos["x"] + pos["w"] <= 24, f"{name} panel {panel['id']}: {pos} exceeds 24 columns"
        for x in range(pos["x"], pos["x"] + pos["w"]):
            for y in range(pos["y"], pos["y"] + pos["h"]):
                assert (x, y) not in taken, f"{name}: panels {taken[(x, y)]} and {panel['id']} overlap at {(x, y)}"
                taken[(x, y)] = panel["id"]


def test_dashboard_basics(board):
    name, doc = board
    assert doc["schemaVersion"] == 42
    assert doc["uid"] == f"tsdb-{name}" and doc["title"]
    assert doc["time"]["from"].startswith("now-") and doc["refresh"]


def _datasource_refs(doc: dict) -> list[tuple[str, dict]]:
    refs = []
    for panel in _panels(doc):
        if panel["type"] == "row":
            continue
        refs.append((f"panel {panel['id']}", panel["datasource"]))
        refs += [(f"panel {panel['id']} target {t['refId']}", t["datasource"]) for t in panel.get("targets", [])]
    for item in doc["annotations"].get("list", []):
        refs.append((f"annotation {item['name']!r}", item["datasource"]))
        refs.append((f"annotation {item['name']!r} target", item["target"]["datasource"]))
    return refs


def test_datasource_uids_match_the_provisioning(board):
    name, doc = board
    provisioned = _provisioned()
    refs = _datasource_refs(doc)
    assert refs
    for where, ref in refs:
        assert ref["uid"] in provisioned, f"{name} {where}: datasource uid {ref['uid']!r} is not provisioned"
        assert ref["type"] == provisioned[ref["uid"]]["type"], f"{name} {where}: type differs from provisioning"
    if name not in kit.DATASOURCES:
        return  # the service dashboard reads Prometheus, not a tenant
    # each use case reads its own tenant
    ds = provisioned[kit.DATASOURCES[name].uid]
    assert ds["secureJsonData"]["httpHeaderValue1"] == kit.DATASOURCES[name].tenancy.service
    assert ds["jsonData"]["httpHeaderName1"] == "Fiware-Service"


def test_every_panel_queries_the_service_through_value_paths():
    for name in USE_CASES:
        targets = [t for p in _panels(dashboards.build(name)) for t in p.get("targets", [])]
        assert targets, name
        assert all(t["url"].startswith("/grafana/infinity/") for t in targets), name
        params = [p["value"] for t in targets for p in t["url_options"]["params"] if p["key"] == "attrs"]
        assert any("(" in value for value in params), f"{name}: no panel reads through a value path"


def test_committed_files_are_what_the_code_builds():
    for relative, content in dashboards.files().items():
        path = ROOT / "dashboards" / relative
        assert path.exists(), f"{path} is missing: run `tsdb-service dashboards build`"
        assert path.read_text() == content, f"{path} is stale: run `tsdb-service dashboards build`"


def test_provisioning_points_grafana_at_the_dashboards():
    doc = yaml.safe_load((ROOT / "dashboards" / "provisioning" / "dashboards.yaml").read_text())
    provider = doc["providers"][0]
    assert provider["type"] == "file" and provider["options"]["path"] == dashboards.GRAFANA_PATH
    assert set(_provisioned()) == {ds.uid for ds in kit.DATASOURCES.values()} | {service.DS.uid}


def test_dashboards_command_writes_and_checks(tmp_path, capsys):
    from tsdb_service.cli.main import main

    assert main(["dashboards", "build", "--out", str(tmp_path)]) == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "drone-ld.json",
        "drone.json",
        "lawnmower.json",
        "provisioning",
        "service.json",
        "warehouse.json",
    ]
    assert main(["dashboards", "build", "--out", str(tmp_path), "--check"]) == 0
    (tmp_path / "drone.json").write_text("{}")
    assert main(["dashboards", "build", "--out", str(tmp_path), "--check"]) == 1


def test_dashboards_are_served(client):
    listed = client.get("/dashboards")
    assert listed.status_code == 200
    assert [d["use_case"] for d in listed.json()] == [*USE_CASES, None, None]  # drone-ld and the service's own
    for item in listed.json():
        one = client.get(item["url"])
        assert one.status_code == 200 and one.json() == dashboards.build(item["name"])
    missing = client.get("/dashboards/nope")
    assert missing.status_code == 404 and missing.json()["error"] == "NotFound"
