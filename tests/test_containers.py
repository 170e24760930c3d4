"""Dockerfile and docker-compose.yml agree with the repository.

No container engine runs here, so the images are never built in the test
suite; what can drift without one is checked instead: images are pinned,
mounted files exist where the dashboards' README says to mount them,
service names and ports match the URLs baked into the provisioning and the
Orion subscriptions, and the one-shot subscriber's command parses.
"""

from __future__ import annotations

import re
from pathlib import Path
from urllib.parse import urlsplit

import pytest
import yaml

from tsdb_service.broker.subscriptions import COMPOSE_NOTIFY_URL
from tsdb_service.cli import build_parser
from tsdb_service.core.config import Settings

ROOT = Path(__file__).resolve().parent.parent
COMPOSE = yaml.safe_load((ROOT / "docker-compose.yml").read_text())
SERVICES = COMPOSE["services"]
DOCKERFILE = (ROOT / "Dockerfile").read_text()


def _instructions(name: str) -> list[str]:
    """Arguments of every ``name`` instruction of the Dockerfile (continuations joined)."""
    text = re.sub(r"\\\n\s*", " ", DOCKERFILE)
    return [line.split(None, 1)[1] for line in text.splitlines() if line.split(None, 1)[:1] == [name]]


def _published(service: str) -> dict[int, int]:
    return {int(p.split(":")[1]): int(p.split(":")[0]) for p in SERVICES[service].get("ports", [])}


def test_the_stack_has_its_services():
    assert set(SERVICES) == {"mongo", "orion", "tsdb-service", "subscriptions", "prometheus", "grafana"}


@pytest.mark.parametrize("service", sorted(SERVICES))
def test_images_are_pinned(service):
    image = SERVICES[service]["image"]
    name, _, tag = image.rpartition(":")
    assert name and tag and tag != "latest" and re.search(r"\d", tag), image


def test_dockerfile_is_small_and_conventional():
    (base,) = _instructions("FROM")
    assert base.startswith("python:3.11.") and "slim" in base
    assert _instructions("USER") == ["tsdb"]
    assert _instructions("EXPOSE") == [str(Settings().port)]
    assert _instructions("VOLUME") == ['["/data"]']
    assert _instructions("ENTRYPOINT") == ['["tsdb-service"]'] and _instructions("CMD") == ['["serve"]']
    (health,) = _instructions("HEALTHCHECK")
    assert "http://127.0.0.1:8668/health" in health
    assert "TSDB_DB=/data/tsdb.duckdb" in " ".join(_instructions("ENV"))
    for copy in _instructions("COPY"):
        for source in copy.split()[:-1]:
            assert (ROOT / source).exists(), source


def test_dockerignore_keeps_local_state_out():
    ignored = set((ROOT / ".dockerignore").read_text().split())
    assert {".git", ".venv", "data", "*.duckdb", "tests"} <= ignored
    assert not ignored & {"tsdb_service", "migrations", "pyproject.toml", "README.md"}


def test_tsdb_service_wiring():
    tsdb = SERVICES["tsdb-service"]
    assert tsdb["build"] == "." and (ROOT / "Dockerfile").is_file()
    assert _published("tsdb-service") == {8668: 8668}
    assert "tsdb-data:/data" in tsdb["volumes"] and "tsdb-data" in COMPOSE["volumes"]
    assert tsdb["environment"]["TSDB_DB"].startswith("/data/")
    # The subscriptions Orion gets notify this service by its compose name.
    notify = urlsplit(COMPOSE_NOTIFY_URL)
    assert (notify.hostname, notify.port, notify.path) == ("tsdb-service", 8668, "/v2/notify")


def test_orion_and_mongo_wiring():
    orion = SERVICES["orion"]
    assert _published("orion") == {1026: 1026}
    assert "mongodb://mongo:27017" in orion["command"]
    assert orion["depends_on"]["mongo"]["condition"] == "service_healthy"
    assert "healthcheck" in SERVICES["mongo"] and "healthcheck" in orion


def test_grafana_mounts_what_the_dashboards_readme_says():
    grafana = SERVICES["grafana"]
    assert "yesoreyeram-infinity-datasource" in grafana["environment"]["GF_PLUGINS_PREINSTALL"]
    mounts = {}
    for volume in grafana["volumes"]:
        source, target = volume.split(":")[:2]
        mounts[target] = source
        if source.startswith("./"):
            assert (ROOT / source).exists(), source
    readme = (ROOT / "dashboards" / "README.md").read_text()
    for target, source in mounts.items():
        if source.startswith("./"):
            assert f"{source}:{target}" in readme, (source, target)
    provider = yaml.safe_load((ROOT / "dashboards/provisioning/dashboards.yaml").read_text())
    assert mounts[provider["providers"][0]["options"]["path"]] == "./dashboards"
    datasources = yaml.safe_load((ROOT / "dashboards/provisioning/datasources.yaml").read_text())["datasources"]
    assert {source["type"] for source in datasources} == {"yesoreyeram-infinity-datasource", "prometheus"}
    for source in datasources:
        url = urlsplit(source["url"])
        assert url.hostname in SERVICES and url.port in _published(url.hostname), source["url"]


def test_subscriptions_run_once_orion_and_the_service_are_healthy():
    job = SERVICES["subscriptions"]
    assert job["image"] == SERVICES["tsdb-service"]["image"] and job["build"] == "." and job["restart"] == "no"
    assert {name: dep["condition"] for name, dep in job["depends_on"].items()} == {
        "orion": "service_healthy",
        "tsdb-service": "service_healthy",
    }
    assert "entrypoint" not in job and _instructions("ENTRYPOINT") == ['["tsdb-service"]']
    args = build_parser().parse_args(job["command"])
    assert (args.command, args.use_case, args.force) == ("subscribe", "all", False)  # keeps what exists
    assert (urlsplit(args.broker).hostname, urlsplit(args.broker).port) == ("orion", 1026)
    assert (args.notify_url or COMPOSE_NOTIFY_URL) == COMPOSE_NOTIFY_URL
