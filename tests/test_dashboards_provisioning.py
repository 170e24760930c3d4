"""``GET /dashboards/provisioning/{datasources,dashboards}.yaml``: the Grafana
provisioning files the explorer's dashboards page offers. The datasources
file names this service at the URL Grafana reaches it by (``?url=``), which
goes into YAML: only a plain ``http(s)://host[:port][/path]`` is taken."""

from __future__ import annotations

import pytest

from tsdb_service.faces.grafana import dashboards
from tsdb_service.faces.grafana.dashboards import kit


@pytest.fixture(scope="module")
def client(client_factory, tmp_path_factory):
    with client_factory(str(tmp_path_factory.mktemp("provisioning") / "tsdb.duckdb")) as c:
        yield c


def test_the_datasources_point_at_the_url_grafana_reaches_us_by(client):
    default = client.get("/dashboards/provisioning/datasources.yaml")
    assert default.status_code == 200 and default.headers["content-type"].startswith("application/yaml")
    assert default.text == dashboards.datasources_yaml(kit.SERVICE_URL)
    for url in ("http://10.0.0.5:8668", "https://tsdb.example.org/history", "http://[::1]:8668"):
        served = client.get("/dashboards/provisioning/datasources.yaml", params={"url": url + "/"})
        assert served.status_code == 200, served.text
        assert served.text == dashboards.datasources_yaml(url)  # the trailing "/" dropped
        for source in kit.DATASOURCES.values():
            assert f"uid: {source.uid}" in served.text


@pytest.mark.parametrize(
    "url",
    [
        "ftp://host:21",
        "http://",
        "http://host:0",
        "http://host:99999",
        "http://user@host:8668",
        "http://host:8668/?q=1",
        "http://host:8668/#x",
        "http://host:8668\n  - name: injected",
        "http://host:8668 #",
        "http://host/" + "a" * 200,
        "host:8668",
    ],
)
def test_anything_but_a_plain_service_url_is_refused(client, url):
    refused = client.get("/dashboards/provisioning/datasources.yaml", params={"url": url})
    assert refused.status_code == 400, url
    assert refused.json()["error"] == "BadRequest" and "url" in refused.json()["description"]


def test_the_dashboard_provider_and_nothing_else(client):
    provider = client.get("/dashboards/provisioning/dashboards.yaml")
    assert provider.status_code == 200 and provider.text == dashboards.dashboards_yaml()
    for name in ("nope.yaml", "..%2Fdatasources.yaml", "prometheus.yml"):
        missing = client.get(f"/dashboards/provisioning/{name}")
        assert missing.status_code == 404, name
