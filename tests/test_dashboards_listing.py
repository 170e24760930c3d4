"""``GET /dashboards`` lists every shipped dashboard: the three use cases and
the service's own (which reads a Prometheus datasource, not Infinity), each
with what it shows (its description, its panels under their rows) and the
datasources its panels use; ``GET /dashboards/service`` serves it."""

from __future__ import annotations

from tsdb_service.faces.grafana import dashboards
from tsdb_service.faces.grafana.dashboards import kit, service


def test_every_dashboard_is_listed_with_its_datasources(client):
    listed = client.get("/dashboards")
    assert listed.status_code == 200, listed.text
    by_name = {d["name"]: d for d in listed.json()}
    assert list(by_name) == list(dashboards.DASHBOARDS) == ["lawnmower", "warehouse", "drone", "drone-ld", "service"]
    for name, source in kit.DATASOURCES.items():
        entry = by_name[name]
        assert entry["use_case"] == name
        assert entry["datasources"] == [{"type": kit.INFINITY, "uid": source.uid}]
        assert entry["datasource_uid"] == source.uid
    own = by_name["service"]
    assert own["use_case"] is None
    assert own["datasources"] == [{"type": service.PROMETHEUS, "uid": service.DS.uid}]
    assert own["datasource_uid"] == service.DS.uid
    assert (own["uid"], own["title"]) == (service.UID, dashboards.build("service")["title"])


def test_the_service_dashboard_is_served(client):
    entry = next(d for d in client.get("/dashboards").json() if d["name"] == "service")
    for url in (entry["url"], "/dashboards/service.json"):
        one = client.get(url)
        assert one.status_code == 200 and one.json() == dashboards.build("service"), url
    missing = client.get("/dashboards/nope")
    assert missing.status_code == 404 and "service" in missing.json()["description"]


def test_each_dashboard_says_what_it_shows(client):
    for entry in client.get("/dashboards").json():
        doc = dashboards.build(entry["name"])
        assert entry["description"] == doc["description"] and entry["description"]
        rows = [panel["title"] for panel in doc["panels"] if panel["type"] == "row"]
        assert [section["title"] for section in entry["sections"]] == rows, entry["name"]
        shown = [title for section in entry["sections"] for title in section["panels"]]
        assert shown == [panel["title"] for panel in doc["panels"] if panel["type"] != "row"], entry["name"]
