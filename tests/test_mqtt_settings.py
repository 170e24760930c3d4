"""MQTT settings (issue 31): off by default; every one a flag and a
``TSDB_*`` variable; a bad one refused before anything starts, in one
``error:`` line naming the flag and its variable, exit status 2. And topic
templates read topics as Orion's ``mqttCustom`` macros write them."""

from __future__ import annotations

import os

import pytest

from tests.support.cli import assert_usage_error, run_cli
from tsdb_service.cli.main import main
from tsdb_service.core.config import Settings
from tsdb_service.ingest.mqtt.config import MqttConfig
from tsdb_service.ingest.mqtt.topics import Route, TopicTemplate

URL = "mqtt://broker:1883"


def test_off_by_default():
    assert Settings().mqtt_url == "" and MqttConfig.from_settings(Settings()) is None


def test_defaults_when_on():
    config = MqttConfig.from_settings(Settings(mqtt_url=URL, mqtt_client_id="tsdb-a"))
    assert config is not None
    assert (config.host, config.port, config.tls, config.qos) == ("broker", 1883, False, 1)
    assert config.filters == ("tsdb/#",) and config.default_tenant is None
    assert config.window == 4 * config.inflight
    shared = MqttConfig.from_settings(Settings(mqtt_url="mqtts://b", mqtt_share_group="g", mqtt_default_tenant="-"))
    assert shared is not None and (shared.port, shared.tls, shared.default_tenant) == (8883, True, "")
    assert shared.filters == ("$share/g/tsdb/#",) and shared.client_id.startswith("tsdb-service-")


@pytest.mark.parametrize(
    ("flags", "needles"),
    [
        (["--mqtt-url", "http://broker:1883"], ["--mqtt-url (TSDB_MQTT_URL)", "mqtt://host:1883"]),
        (["--mqtt-url", "mqtt://user:secret@broker"], ["--mqtt-url (TSDB_MQTT_URL)", "--mqtt-username"]),
        (["--mqtt-url", "mqtt://broker:99999"], ["--mqtt-url (TSDB_MQTT_URL)", "port"]),
        (["--mqtt-url", "mqtt://broker/topic"], ["--mqtt-url (TSDB_MQTT_URL)", "--mqtt-topics"]),
        (["--mqtt-url", URL, "--mqtt-qos", "2"], ["--mqtt-qos (TSDB_MQTT_QOS)", "1"]),
        (["--mqtt-url", URL, "--mqtt-topics", "a/#/b"], ["--mqtt-topics (TSDB_MQTT_TOPICS)", "'#'"]),
        (["--mqtt-url", URL, "--mqtt-topics", "$share/g/a"], ["--mqtt-topics (TSDB_MQTT_TOPICS)", "share-group"]),
        (["--mqtt-url", URL, "--mqtt-topic-template", "t/+/${service}"], ["--mqtt-topic-template", "wildcards"]),
        (["--mqtt-url", URL, "--mqtt-topic-template", "${service}/${service}"], ["--mqtt-topic-template", "twice"]),
        (["--mqtt-url", URL, "--mqtt-default-tenant", "a b"], ["--mqtt-default-tenant (TSDB_MQTT_DEFAULT_TENANT)"]),
        (["--mqtt-url", URL, "--mqtt-share-group", "a/b"], ["--mqtt-share-group (TSDB_MQTT_SHARE_GROUP)"]),
        (["--mqtt-url", URL, "--mqtt-password", "x"], ["--mqtt-password (TSDB_MQTT_PASSWORD)", "USERNAME"]),
        (["--mqtt-url", URL, "--mqtt-ca-file", "/nonexistent"], ["--mqtt-ca-file (TSDB_MQTT_CA_FILE)", "mqtts://"]),
        (["--mqtt-url", "mqtts://b", "--mqtt-ca-file", "/nonexistent"], ["--mqtt-ca-file", "not a readable file"]),
        (["--mqtt-topics", "a/#"], ["--mqtt-topics (TSDB_MQTT_TOPICS)", "TSDB_MQTT_URL is not"]),
        (["--mqtt-url", URL, "--mqtt-inflight", "0"], ["--mqtt-inflight (TSDB_MQTT_INFLIGHT)"]),
    ],
)
def test_a_bad_mqtt_setting_is_one_line(tmp_path, monkeypatch, capsys, flags, needles):
    for name in list(os.environ):
        if name.startswith("TSDB_"):
            monkeypatch.delenv(name)
    monkeypatch.chdir(tmp_path)
    assert main(["serve", "--db", str(tmp_path / "db.duckdb"), *flags]) == 2
    assert_usage_error(_Done(capsys.readouterr().err), *needles)
    assert list(tmp_path.iterdir()) == [], "nothing may be created for a refused setting"


class _Done:
    """What ``assert_usage_error`` reads of a finished command."""

    def __init__(self, stderr: str):
        self.returncode, self.stdout, self.stderr = 2, "", stderr


def test_as_an_operator_meets_it(tmp_path):
    """The real command, with the setting as a variable; several workers cannot share one MQTT session."""
    done = run_cli("serve", "--db", str(tmp_path / "db"), env={"TSDB_MQTT_URL": "mqtt://broker:1883/x"}, cwd=tmp_path)
    assert_usage_error(done, "--mqtt-url (TSDB_MQTT_URL)")
    done = run_cli("serve", "--db", "postgresql://u@h/db", "--workers", "2", "--mqtt-url", URL, cwd=tmp_path)
    assert_usage_error(done, "--mqtt-url with --workers > 1", "--mqtt-client-id")


@pytest.mark.parametrize(
    ("template", "topic", "route"),
    [
        ("tsdb/${service}${servicePath}", "tsdb/acme/floor1/room2", Route("acme", "/floor1/room2")),
        ("tsdb/${service}${servicePath}", "tsdb/acme/", Route("acme", "/")),
        ("tsdb/${service}${servicePath}", "tsdb/acme", Route("acme", "/")),
        ("tsdb/${service}${servicePath}", "tsdb//", Route("", "/")),  # Orion's default tenant
        ("tsdb/${service}${servicePath}", "other/acme/", None),
        ("o/${service}${servicePath}/${type}/${id}", "o/acme/a/b/Robot/r1", Route("acme", "/a/b")),
        ("o/${service}/${id}", "o/acme/r1", Route("acme", None)),
        ("fixed/topic", "fixed/topic", Route("", None)),
        ("fixed/topic", "fixed/topic/x", None),
    ],
)
def test_templates_read_topics_as_orion_writes_them(template, topic, route):
    assert TopicTemplate.parse(template).match(topic) == route


@pytest.mark.parametrize(
    ("template", "subscribed"),
    [
        ("tsdb/${service}${servicePath}", "tsdb/#"),
        ("a/b/${service}", "a/b/#"),
        ("a/b-${service}", "a/#"),
        ("${service}${servicePath}", "#"),
        ("fixed/topic", "fixed/topic"),
    ],
)
def test_a_template_says_what_to_subscribe_to(template, subscribed):
    assert TopicTemplate.parse(template).filter == subscribed
