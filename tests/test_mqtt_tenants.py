"""MQTT honours tenant restrictions as HTTP does (issue 37, finding 6).

Over HTTP a broker key limited to tenant ``alpha`` is refused on ``beta``;
over MQTT anyone who could publish on ``tsdb/#`` wrote any tenant.
``TSDB_MQTT_TENANTS`` says which tenants each topic may write: a message
for another tenant, whether the topic names it, a header does or the
default tenant applies, is rejected (kept in the rejected store, with its
topic), never written. Against the run's Mosquitto, on both backends.
"""

from __future__ import annotations

import time

import orjson
import pytest

from tests.support.mosquitto import Publisher, mqtt_settings, unique_client_id
from tsdb_service.core.config import Settings
from tsdb_service.ingest.mqtt.config import MqttConfig
from tsdb_service.ingest.mqtt.topics import filter_matches, parse_tenant_rules, topic_tenants


def body(entity_id: str, value: int) -> bytes:
    entity = {"id": entity_id, "type": "Robot", "n": {"type": "Number", "value": value}}
    return orjson.dumps({"subscriptionId": "t", "data": [entity]})


def envelope(headers: dict, entity_id: str) -> bytes:
    return orjson.dumps({"metadata": headers, "body": orjson.loads(body(entity_id, 1))})


@pytest.fixture
def feed(client_factory, store_url, mosquitto):
    prefix = unique_client_id("tenants")
    rules = f"{prefix}/v2/alpha/#=alpha; {prefix}/site/+/robots=alpha,-"
    settings = mqtt_settings(
        mosquitto.url, prefix, "v2/${service}${servicePath}", mqtt_default_tenant="-", mqtt_tenants=rules
    )
    with client_factory(store_url, **settings) as client, Publisher(mosquitto.url) as publisher:
        consumer = client.app.state.mqtt
        assert consumer.subscribed.wait(10)
        yield prefix, client, publisher, consumer


def settle(consumer, count: int) -> None:
    deadline = time.monotonic() + 20
    while consumer.stats.stored + consumer.stats.rejected < count:
        assert time.monotonic() < deadline, consumer.stats
        time.sleep(0.02)


def holds(client, tenant: str, entity_id: str) -> bool:
    """Does ``tenant`` hold samples of ``entity_id``?"""
    headers = {"Fiware-Service": tenant} if tenant else {}
    response = client.get(f"/v2/entities/{entity_id}", headers=headers)
    return response.status_code == 200 and bool(response.json()) and bool(response.json()["index"])


def test_a_topic_writes_only_its_tenants(feed):
    prefix, client, publisher, consumer = feed
    sent = [
        (f"{prefix}/v2/alpha/floor", body("Ok:1", 1), None),  # the rule's tenant: stored
        (f"{prefix}/v2/beta/floor", body("No:1", 1), None),  # a tenant the topic may not write
        (f"{prefix}/v2/alpha", envelope({"Fiware-Service": "beta"}, "No:2"), None),  # topic and header disagree
        (f"{prefix}/plain", body("No:3", 1), [("Fiware-Service", "alpha")]),  # no rule matches the topic
        (f"{prefix}/plain", body("No:4", 1), None),  # the default tenant: no rule matches the topic
        (f"{prefix}/site/x/robots", body("Ok:2", 2), [("Fiware-Service", "alpha")]),  # a '+' rule
        (f"{prefix}/site/x/robots", body("Ok:3", 3), None),  # the default tenant, which '-' allows
        (f"{prefix}/site/x/robots", body("No:5", 5), [("Fiware-Service", "gamma")]),
    ]
    for topic, payload, properties in sent:
        publisher.publish(topic, payload, user_properties=properties)
    settle(consumer, len(sent))
    client.app.state.store.sync()
    assert (consumer.stats.stored, consumer.stats.rejected) == (3, 5)
    assert holds(client, "alpha", "Ok:1") and holds(client, "alpha", "Ok:2") and holds(client, "", "Ok:3")
    for tenant in ("alpha", "beta", "gamma", ""):
        for n in range(1, 6):
            assert not holds(client, tenant, f"No:{n}")
    rejected = client.get("/v2/notify/rejected", params={"allTenants": "true"}).json()
    forbidden = {(r["tenant"], r["topic"]) for r in rejected if r["error"] == "Forbidden"}
    assert forbidden == {
        ("beta", f"{prefix}/v2/beta/floor"),
        ("alpha", f"{prefix}/plain"),
        ("", f"{prefix}/plain"),
        ("gamma", f"{prefix}/site/x/robots"),
    }
    refused = next(r for r in rejected if r["topic"] == f"{prefix}/v2/beta/floor")
    assert "TSDB_MQTT_TENANTS" in refused["description"] and "'beta'" in refused["description"]


@pytest.mark.parametrize(
    ("topic_filter", "topic", "hit"),
    [
        ("tsdb/alpha/#", "tsdb/alpha", True),
        ("tsdb/alpha/#", "tsdb/alpha/x/y", True),
        ("tsdb/alpha/#", "tsdb/alphabet/x", False),
        ("tsdb/+/robots", "tsdb/a/robots", True),
        ("tsdb/+/robots", "tsdb/a/b/robots", False),
        ("tsdb/+", "tsdb/a/b", False),
        ("#", "$SYS/x", False),
        ("tsdb/a", "tsdb/a", True),
        ("tsdb/a", "tsdb/a/", False),
    ],
)
def test_filters_match_as_mqtt_says(topic_filter, topic, hit):
    assert filter_matches(topic_filter, topic) is hit


def test_rules_union_over_matching_filters():
    rules = parse_tenant_rules("tsdb/#=Alpha; tsdb/shared/#=beta,-")
    assert topic_tenants(rules, "tsdb/shared/x") == {"alpha", "beta", ""}
    assert topic_tenants(rules, "tsdb/x") == {"alpha"}
    assert topic_tenants(rules, "other/x") == set()


@pytest.mark.parametrize(
    ("spec", "needle"),
    [
        ("tsdb/#", "FILTER=TENANT"),
        ("=alpha", "FILTER=TENANT"),
        ("tsdb/#=al pha", "is not a tenant"),
        ("tsdb/#=", "is not a tenant"),
        ("tsdb/a#=alpha", "'#' must be a whole level"),
        ("tsdb/#=alpha,beta-1", "is not a tenant"),
    ],
)
def test_a_bad_rule_is_refused_at_start(spec, needle):
    settings = Settings(mqtt_url="mqtt://localhost", mqtt_tenants=spec)
    with pytest.raises(ValueError, match="TSDB_MQTT_TENANTS") as caught:
        MqttConfig.from_settings(settings)
    assert needle in str(caught.value)


def test_rules_without_mqtt_are_a_mistake():
    with pytest.raises(ValueError, match="TSDB_MQTT_TENANTS is set but TSDB_MQTT_URL is not"):
        MqttConfig.from_settings(Settings(mqtt_tenants="tsdb/#=alpha"))
