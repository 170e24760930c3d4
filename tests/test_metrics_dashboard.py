"""The service dashboard reads only metrics the service really exposes.

Schema, SDK round trip and layout are checked with every other dashboard in
test_grafana_schema; this is the contract between service.json's PromQL and
``GET /metrics``: a renamed metric would leave a panel silently empty."""

from __future__ import annotations

import re

from prometheus_client.parser import text_string_to_metric_families

from tests.grafana_fixtures import panels_of
from tsdb_service.faces.grafana import dashboards
from tsdb_service.faces.grafana.dashboards import service

SUFFIXES = {"counter": ("_total",), "histogram": ("_bucket", "_sum", "_count"), "gauge": ("",)}
METRIC = re.compile(r"\b((?:tsdb|process)_[a-z_]+)\b")


def exposed_names(client) -> set[str]:
    text = client.get("/metrics").text
    return {
        family.name + suffix
        for family in text_string_to_metric_families(text)
        for suffix in SUFFIXES.get(family.type, ("",))
    }


def test_every_query_names_an_exposed_metric(client):
    exposed = exposed_names(client)
    targets = [t for p in panels_of(dashboards.build("service")) for t in p.get("targets", [])]
    assert targets
    for target in targets:
        assert target["datasource"] == {"type": "prometheus", "uid": service.DS.uid}
        names = METRIC.findall(target["expr"])
        assert names, target["expr"]
        missing = [n for n in names if n not in exposed]
        assert not missing, f"{target['expr']}: not exposed by /metrics: {missing}"


def test_queries_group_by_bounded_labels_only():
    grouped = set()
    for panel in panels_of(dashboards.build("service")):
        for target in panel.get("targets", []):
            for by in re.findall(r"by \(([^)]*)\)", target["expr"]):
                grouped |= {label.strip() for label in by.split(",")}
    assert grouped <= {"le", "tenant", "reason", "route", "status"}, grouped
