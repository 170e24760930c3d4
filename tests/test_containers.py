"""Dockerfile, docker-compose.yml and its Orion-LD and MQTT variants agree with the repository.

No container engine runs here, so the images are never built in the test
suite; what can drift without one is checked instead: both compose files,
and the stack they make together, are valid under the Compose
Specification's JSON schema (vendored in tests/support/compose-spec/ with
its licence); images are pinned; mounted files exist where the dashboards'
README says to mount them; service names and ports match the URLs baked into
the provisioning and the subscriptions; the subscriber's and the feeder's
commands parse; the image installs no extras and carries only the pruned
virtual environment. tests/test_broker_feed.py runs the same two commands
against a stand-in broker.
"""

from __future__ import annotations

import json
import re
import subprocess
from pathlib import Path
from urllib.parse import urlsplit

import jsonschema
import pytest
import yaml

from tsdb_service.broker.subscriptions import COMPOSE_NOTIFY_URL, MQTT_TOPIC
from tsdb_service.cli.main import build_parser
from tsdb_service.core.config import Settings

ROOT = Path(__file__).resolve().parent.parent
COMPOSE = yaml.safe_load((ROOT / "docker-compose.yml").read_text())
SERVICES = COMPOSE["services"]
ORION_LD = yaml.safe_load((ROOT / "docker-compose.orion-ld.yml").read_text())
MQTT = yaml.safe_load((ROOT / "docker-compose.mqtt.yml").read_text())
DOCKERFILE = (ROOT / "Dockerfile").read_text()
SCHEMA = json.loads((ROOT / "tests/support/compose-spec/compose-spec.json").read_text())


def merged(base: dict, override: dict) -> dict:
    """``docker compose -f base -f override``: mappings merge key by key, and a
    scalar or a sequence (``command``, ``image``) replaces the base's."""
    out = dict(base)
    for key, value in override.items():
        out[key] = merged(base[key], value) if isinstance(value, dict) and isinstance(base.get(key), dict) else value
    return out


STACK_LD = merged(COMPOSE, ORION_LD)
STACK_MQTT = merged(COMPOSE, MQTT)


def _problems(document: dict) -> list[str]:
    validator = jsonschema.Draft7Validator(SCHEMA, format_checker=jsonschema.Draft7Validator.FORMAT_CHECKER)
    return [f"{'/'.join(map(str, e.absolute_path))}: {e.message}" for e in validator.iter_errors(document)]


@pytest.mark.parametrize(
    "document",
    [COMPOSE, ORION_LD, STACK_LD, MQTT, STACK_MQTT],
    ids=["docker-compose.yml", "orion-ld override", "the Orion-LD stack", "mqtt override", "the MQTT stack"],
)
def test_compose_files_follow_the_compose_specification(document):
    assert _problems(document) == []


def test_the_validator_catches_what_compose_would_refuse():
    broken = merged(COMPOSE, {"services": {"feeder": {"depends_on": {"subscriptions": {"condition": "done"}}}}})
    assert _problems(broken) and _problems(merged(COMPOSE, {"services": {"orion": {"ports": 1026}}}))


def test_the_orion_ld_variant_only_changes_what_it_says():
    assert set(ORION_LD["services"]) <= set(SERVICES)
    assert set(ORION_LD) == {"services"}
    assert STACK_LD["services"]["orion"]["image"].startswith("fiware/orion-ld:")
    assert "-dbhost" in STACK_LD["services"]["orion"]["command"] and "mongo" in STACK_LD["services"]["orion"]["command"]


def _instructions(name: str) -> list[str]:
    """Arguments of every ``name`` instruction of the Dockerfile (continuations joined)."""
    text = re.sub(r"\\\n\s*", " ", DOCKERFILE)
    return [line.split(None, 1)[1] for line in text.splitlines() if line.split(None, 1)[:1] == [name]]


def _published(service: str) -> dict[int, int]:
    return {int(p.split(":")[1]): int(p.split(":")[0]) for p in SERVICES[service].get("ports", [])}


def test_the_stack_has_its_services():
    assert set(SERVICES) == {"mongo", "orion", "tsdb-service", "subscriptions", "feeder", "prometheus", "grafana"}


@pytest.mark.parametrize("service", sorted(STACK_MQTT["services"]))
def test_images_are_pinned(service):
    image = STACK_MQTT["services"][service]["image"]
    name, _, tag = image.rpartition(":")
    assert name and tag and tag != "latest" and re.search(r"\d", tag), image


def _stages() -> list[str]:
    """The Dockerfile's build stages, each from its FROM line on."""
    return re.split(r"(?m)^(?=FROM )", DOCKERFILE)[1:]


def test_dockerfile_is_small_and_conventional():
    bases = _instructions("FROM")
    assert len(bases) == 2 and bases[0].endswith(" AS build"), bases
    for base in bases:
        assert base.split()[0].startswith("python:3.11.") and "slim" in base
    build, runtime = _stages()
    # Runtime dependencies only, from the hash-locked list (tests/test_image_lock.py), the
    # package without resolving anything (no [test] or [bench] extras), pruned, then copied alone.
    installs = re.findall(r"/opt/tsdb/bin/pip install ([^&\n]*)", re.sub(r"\\\n\s*", " ", build))
    assert [i.split() for i in installs] == [
        ["--require-hashes", "--no-deps", "-r", "requirements.lock"],
        ["--no-deps", "dist/*.whl"],
    ]
    assert "/opt/tsdb/bin/pip check" in build
    assert "prune-venv.sh /opt/tsdb/lib/python3.11/site-packages" in build
    assert re.findall(r"(?m)^COPY .*", runtime) == ["COPY --from=build /opt/tsdb /opt/tsdb"]
    assert "pip" not in runtime.replace("PIP_", "")
    assert _instructions("USER") == ["tsdb"]
    assert _instructions("EXPOSE") == [str(Settings().port)]
    assert _instructions("VOLUME") == ['["/data"]']
    assert _instructions("ENTRYPOINT") == ['["tsdb-service"]'] and _instructions("CMD") == ['["serve"]']
    (health,) = _instructions("HEALTHCHECK")
    assert "http://127.0.0.1:8668/health" in health
    assert "TSDB_DB=/data/tsdb.duckdb" in " ".join(_instructions("ENV"))
    assert "PATH=/opt/tsdb/bin:$PATH" in " ".join(_instructions("ENV"))
    for copy in _instructions("COPY"):
        if copy.startswith("--from="):
            continue
        for source in copy.split()[:-1]:
            assert (ROOT / source).exists(), source


def test_the_prune_script_removes_only_what_the_service_never_loads(tmp_path):
    """docker/prune-venv.sh on a site-packages tree laid out as pip leaves it.
    (On a real environment: 572 -> 412 MB, the service, the demo and both
    export formats still working; docs/containers.md.)"""
    site = tmp_path / "site-packages"
    removed = [
        "pip/__init__.py",
        "setuptools/__init__.py",
        "pkg_resources/__init__.py",
        "_distutils_hack/__init__.py",
        "distutils-precedence.pth",
        "pandas/tests/test_x.py",
        "numpy/_core/tests/test_y.py",
        "pyarrow/tests/test_z.py",
        "pyarrow/include/arrow/api.h",
        "pyarrow/lib.pyx",
        "pyarrow/lib.pxd",
        "pyarrow/_flight.cpython-311-x86_64-linux-gnu.so",
        "pyarrow/libarrow_flight.so.2600",
        "pyarrow/libarrow_python_flight.so.2600",
        "pyarrow/_s3fs.cpython-311-x86_64-linux-gnu.so",
        "pyarrow/libarrow_s3.so.2600",
        "pyarrow/libarrow_python.so",
        "pyarrow/libarrow_python.so.2600.1.0",
    ]
    kept = [
        "tsdb_service/cli/main.py",
        "tsdb_service/faces/ui/static/explorer.js",
        "pyarrow/libarrow.so.2600",
        "pyarrow/libarrow_python.so.2600",
        "pyarrow/libparquet.so.2600",
        "pyarrow/_parquet.cpython-311-x86_64-linux-gnu.so",
        "pyarrow/fs.py",
        "pandas/testing.py",
        "_duckdb.cpython-311-x86_64-linux-gnu.so",
        "duckdb/__init__.py",
    ]
    for name in removed + kept:
        (site / name).parent.mkdir(parents=True, exist_ok=True)
        (site / name).write_text("x")
    done = subprocess.run(["sh", str(ROOT / "docker" / "prune-venv.sh"), str(site)], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    left = {str(path.relative_to(site)) for path in site.rglob("*") if path.is_file()}
    assert left == set(kept)


def test_dockerignore_keeps_local_state_out():
    lines = (ROOT / ".dockerignore").read_text().splitlines()
    ignored = {line.strip() for line in lines if line.strip() and not line.startswith("#")}
    assert {".git", ".venv", "data", "*.duckdb", "tests", "docs", "site", "benchmarks"} <= ignored
    assert not ignored & {"tsdb_service", "migrations", "pyproject.toml", "README.md", "docker", "*.lock"}
    assert not any(name.startswith("requirements") for name in ignored)


def test_tsdb_service_wiring():
    tsdb = SERVICES["tsdb-service"]
    assert tsdb["build"] == "." and (ROOT / "Dockerfile").is_file()
    assert _published("tsdb-service") == {8668: 8668}
    assert "tsdb-data:/data" in tsdb["volumes"] and "tsdb-data" in COMPOSE["volumes"]
    assert tsdb["environment"]["TSDB_DB"].startswith("/data/")
    # The recorded subscriptions (notifications/) notify this service by its compose name.
    notify = urlsplit(COMPOSE_NOTIFY_URL)
    assert (notify.hostname, notify.port, notify.path) == ("tsdb-service", 8668, "/v2/notify")


def test_orion_and_mongo_wiring():
    orion = SERVICES["orion"]
    assert _published("orion") == {1026: 1026}
    assert "mongodb://mongo:27017" in orion["command"]
    assert orion["depends_on"]["mongo"]["condition"] == "service_healthy"
    assert "healthcheck" in SERVICES["mongo"] and "healthcheck" in orion


INFINITY = "yesoreyeram-infinity-datasource@3.11.1"


def test_the_infinity_plugin_is_pinned():
    """Grafana installs ``id@version`` before it starts; an unpinned id took the newest release."""
    environment = SERVICES["grafana"]["environment"]
    assert environment["GF_PLUGINS_PREINSTALL_SYNC"] == INFINITY
    assert not {"GF_PLUGINS_PREINSTALL", "GF_INSTALL_PLUGINS"} & set(environment)
    readme = (ROOT / "dashboards" / "README.md").read_text()
    assert f"GF_PLUGINS_PREINSTALL_SYNC: {INFINITY}" in readme and f"GF_PLUGINS_PREINSTALL_SYNC={INFINITY}" in readme


@pytest.mark.parametrize("stack", [COMPOSE, STACK_LD, STACK_MQTT], ids=["base", "Orion-LD", "MQTT"])
def test_every_long_running_service_restarts(stack):
    """After a crash and with the Docker daemon; the one-shot subscriptions job stays done."""
    for name, service in stack["services"].items():
        expected = "no" if name == "subscriptions" else "unless-stopped"
        assert service.get("restart") == expected, name


def test_grafana_mounts_what_the_dashboards_readme_says():
    grafana = SERVICES["grafana"]
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


@pytest.mark.parametrize("stack", [COMPOSE, STACK_LD], ids=["Orion", "Orion-LD"])
def test_subscriptions_run_once_orion_and_the_service_are_healthy(stack):
    services = stack["services"]
    job = services["subscriptions"]
    assert job["image"] == services["tsdb-service"]["image"] and job["build"] == "." and job["restart"] == "no"
    assert {name: dep["condition"] for name, dep in job["depends_on"].items()} == {
        "orion": "service_healthy",
        "tsdb-service": "service_healthy",
    }
    assert "entrypoint" not in job and _instructions("ENTRYPOINT") == ['["tsdb-service"]']
    args = build_parser().parse_args(job["command"])
    assert (args.command, args.use_case, args.force) == ("subscribe", "all", False)  # keeps what exists
    assert (urlsplit(args.broker).hostname, urlsplit(args.broker).port) == ("orion", 1026)
    # Orion reaches the service by its compose name; the path is the API the broker speaks.
    notify = urlsplit(args.notify_url)
    assert (notify.hostname, notify.port) == ("tsdb-service", 8668)
    assert notify.path == ("/ngsi-ld/v1/notify" if args.ngsi_ld else "/v2/notify")
    assert args.ngsi_ld == ("orion-ld" in services["orion"]["image"])


@pytest.mark.parametrize("stack", [COMPOSE, STACK_LD], ids=["Orion", "Orion-LD"])
def test_the_feeder_updates_orion_once_subscribed(stack):
    """Data goes through the broker, as in a deployment: the feeder sends entity
    updates to Orion, never notifications to tsdb-service."""
    services = stack["services"]
    feeder = services["feeder"]
    assert feeder["image"] == services["tsdb-service"]["image"] and "build" not in feeder
    assert feeder["depends_on"] == {"subscriptions": {"condition": "service_completed_successfully"}}
    args = build_parser().parse_args(feeder["command"])
    assert (args.command, args.no_serve, args.duration) == ("demo", True, None)  # live until the stack stops
    assert (urlsplit(args.broker).hostname, urlsplit(args.broker).port) == ("orion", 1026)
    assert urlsplit(args.url).hostname == "tsdb-service"
    assert args.ngsi_ld == build_parser().parse_args(services["subscriptions"]["command"]).ngsi_ld


def test_the_mqtt_variant_puts_mosquitto_between_orion_and_the_service():
    """Orion publishes to Mosquitto (the subscriptions say so), the service
    consumes the same broker under a fixed client id (its session holds what
    arrives while it is away), and the topics agree: what ``subscribe --mqtt``
    has Orion publish on is what the service's default template reads."""
    assert set(MQTT) == {"services", "volumes"} and set(MQTT["services"]) - set(SERVICES) == {"mosquitto"}
    services = STACK_MQTT["services"]
    broker = services["mosquitto"]
    assert broker["image"].startswith("eclipse-mosquitto:2.")
    assert {int(p.split(":")[1]) for p in broker["ports"]} == {1883}
    mounts = dict(volume.split(":")[1::-1] for volume in broker["volumes"])
    assert mounts["/mosquitto/data"] in MQTT["volumes"]  # sessions and queues outlive the container
    config = ROOT / mounts["/mosquitto/config/mosquitto.conf"]
    lines = {tuple(line.split()) for line in config.read_text().splitlines() if line and not line.startswith("#")}
    assert {("listener", "1883"), ("persistence", "true"), ("persistence_location", "/mosquitto/data/")} <= lines
    assert ("max_queued_messages", "0") in lines  # not the default 1,000, past which QoS 1 messages are dropped
    assert "mosquitto_sub" in broker["healthcheck"]["test"]

    tsdb = services["tsdb-service"]
    settings = Settings(**{k.removeprefix("TSDB_").lower(): v for k, v in tsdb["environment"].items()})
    url = urlsplit(settings.mqtt_url)
    assert (url.scheme, url.hostname, url.port) == ("mqtt", "mosquitto", 1883)
    assert settings.mqtt_client_id and tsdb["depends_on"] == {"mosquitto": {"condition": "service_healthy"}}

    args = build_parser().parse_args(services["subscriptions"]["command"])
    assert (args.command, args.use_case, args.force, args.notify_url) == ("subscribe", "all", False, None)
    assert args.mqtt == settings.mqtt_url and args.mqtt_topic is None
    assert settings.mqtt_topic_template == MQTT_TOPIC  # what Orion publishes on is what the service reads
    assert services["feeder"] == SERVICES["feeder"]  # the data still goes through Orion
