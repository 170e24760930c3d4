"""Notifications over MQTT (issue 31), through a real broker, on both backends.

Every payload shape a broker publishes is stored and read back exactly as
the same notification posted to ``/v2/notify`` is: Orion's bare NGSIv2
bodies in each ``attrsFormat`` (the tenant and service path from the topic,
``mqttCustom``'s ``tsdb/${service}${servicePath}``), Orion-LD's
``{"metadata", "body"}`` envelopes in each attribute format and as GeoJSON
(the tenant from the metadata), NGSIv1 ``legacy``, and MQTT 5 user
properties as headers. A message we cannot use is kept in the rejected store
with its topic. The broker is Debian's mosquitto (tests/support/mosquitto.py).
"""

from __future__ import annotations

import json
from pathlib import Path

import orjson
import pytest

from tests.support.mosquitto import Publisher
from tests.support.mqtt_service import Feed, T, consuming, rejected_on, timed, v2

PAYLOADS = Path(__file__).parent / "payloads"


def envelope(headers: dict, body: dict) -> dict:
    """What Orion-LD publishes: its HTTP headers as ``metadata``, the Link
    header reduced to the context URL (mqttNotify.cpp)."""
    metadata = {k: v for k, v in headers.items() if k not in ("Content-Length", "Host")}
    if "Link" in metadata:
        metadata["Link"] = metadata["Link"].split(">")[0].lstrip("<")
    return {"metadata": metadata, "body": body}


def recorded(name: str) -> dict:
    return json.loads((PAYLOADS / name).read_text())


# (case, entity id, NGSIv2 body or None, LD record or None, HTTP headers besides the tenant's)
V2_CASES = {
    "normalized": v2({"id": "R:norm", "type": "Robot", "temperature": timed(21.5), "on": timed(True, "Boolean")}),
    "keyValues": v2({"id": "R:kv", "type": "Robot", "temperature": 22.25, "TimeInstant": T, "where": [1, 2]}),
    "simplifiedNormalized": {"id": "R:sn", "type": "Robot", "speed": timed(0.5), "name": timed("Rover", "Text")},
    "simplifiedKeyValues": {"id": "R:skv", "type": "Robot", "speed": 1.5, "TimeInstant": T},
    "legacy": {
        "subscriptionId": "s",
        "originator": "localhost",
        "contextResponses": [
            {
                "contextElement": {
                    "id": "R:v1",
                    "type": "Robot",
                    "isPattern": "false",
                    "attributes": [
                        {"name": "temperature", "type": "float", "value": "23", "metadatas": []},
                        {"name": "TimeInstant", "type": "ISO8601", "value": T},
                    ],
                },
                "statusCode": {"code": "200", "reasonPhrase": "OK"},
            }
        ],
    },
}
LD_CASES = ["ngsi-ld/normalized.json", "ngsi-ld/concise.json", "ngsi-ld/simplified.json", "geojson/normalized.json"]


def entity_of(case: str) -> str:
    if case in V2_CASES:
        body = V2_CASES[case]
        data = body.get("data") or [body.get("contextResponses", [{}])[0].get("contextElement", body)]
        return data[0]["id"]
    return recorded(case)["expect"]["entity"]


def tenants(case: str) -> tuple[str, str]:
    """(the MQTT copy's tenant, the HTTP copy's)."""
    slug = case.replace("/", "_").replace(".json", "").replace("-", "_").lower()
    return f"mq_{slug}", f"ht_{slug}"


@pytest.fixture(scope="module")
def feed(client_factory, store_url_factory, mosquitto):
    prefix, client = consuming(client_factory, store_url_factory("mqtt_ingest"), mosquitto)
    with client, Publisher(mosquitto.url) as publisher:
        yield Feed(client, client.app, publisher, prefix)


@pytest.fixture(scope="module")
def shapes(feed):
    """Every case twice: published over MQTT, posted over HTTP."""
    for case, body in V2_CASES.items():
        mq, ht = tenants(case)
        feed.publish(f"v2/{mq}/robots", body)
        headers = {"Content-Type": "application/json", "Fiware-Service": ht, "Fiware-ServicePath": "/robots"}
        assert feed.client.post("/v2/notify", content=orjson.dumps(body), headers=headers).status_code == 200
    for case in LD_CASES:
        record = recorded(case)
        mq, ht = tenants(case)
        feed.publish("ld", envelope({**record["headers"], "Ngsild-Tenant": mq}, record["body"]))
        headers = {**record["headers"], "Ngsild-Tenant": ht}
        assert feed.client.post("/ngsi-ld/v1/notify", content=orjson.dumps(record["body"]), headers=headers).is_success
    feed.settled(len(V2_CASES) + len(LD_CASES))
    return feed


@pytest.mark.parametrize("case", [*V2_CASES, *LD_CASES])
def test_every_payload_shape_reads_back_as_the_same_notification_over_http(shapes, case):
    mq, ht = tenants(case)
    path = "/robots" if case in V2_CASES else None
    over_mqtt = shapes.history(entity_of(case), mq, path)
    over_http = shapes.history(entity_of(case), ht, path)
    assert over_mqtt[0] == 200, over_mqtt
    if case in LD_CASES and "time" not in recorded(case)["expect"]:
        for _, entity in (over_mqtt, over_http):  # no time in the body: stored at the reception time
            del entity["index"]
    assert over_mqtt == over_http


@pytest.mark.parametrize("case", LD_CASES)
def test_orion_ld_envelopes_read_back_exactly(shapes, case):
    expect = recorded(case)["expect"]
    _, entity = shapes.history(expect["entity"], tenants(case)[0])
    got = {a["attrName"]: a["values"][-1] for a in entity["attributes"]}
    assert {name: got[name] for name in expect["values"]} == expect["values"]
    if "time" in expect:
        assert entity["index"][-1] == expect["time"]


def test_normalized_values_exactly(shapes):
    status, entity = shapes.history("R:norm", tenants("normalized")[0], "/robots")
    assert (status, entity["index"]) == (200, ["2025-02-03T04:05:06.789+00:00"])
    assert {a["attrName"]: a["values"] for a in entity["attributes"]} == {"temperature": [21.5], "on": [True]}


def test_tenant_and_service_path_come_from_the_topic(feed):
    before = feed.consumer.stats.stored
    feed.publish("v2/acme/floor1/room2", v2({"id": "R:deep", "type": "Robot", "x": timed(1)}))
    feed.publish("v2//", v2({"id": "R:default", "type": "Robot", "x": timed(2)}))  # Orion's default tenant, path /
    feed.publish("v2/acme", v2({"id": "R:nopath", "type": "Robot", "x": timed(3)}))
    feed.settled(feed.published)
    assert feed.consumer.stats.stored == before + 3
    assert feed.history("R:deep", "acme", "/floor1/room2")[1]["attributes"] == [{"attrName": "x", "values": [1]}]
    assert feed.history("R:deep", "acme", "/floor1")[0] == 200  # a path reads what is below it
    assert feed.history("R:deep", "acme", "/elsewhere")[1] == []  # nothing under another path
    assert feed.history("R:default", "")[0] == 200
    assert feed.history("R:nopath", "acme", "/")[0] == 200


def test_tenant_from_metadata_and_from_user_properties(feed):
    record = recorded("ngsi-ld/normalized.json")
    feed.publish("ld", envelope({**record["headers"], "Ngsild-Tenant": "from_metadata"}, record["body"]))
    body = v2({"id": "R:props", "type": "Robot", "temperature": 30, "TimeInstant": T})
    feed.publish("props", body, user_properties=[("Fiware-Service", "from_props"), ("Ngsiv2-AttrsFormat", "keyValues")])
    feed.settled(feed.published)
    assert feed.history(record["expect"]["entity"], "from_metadata")[0] == 200
    status, entity = feed.history("R:props", "from_props")
    assert status == 200 and {"attrName": "temperature", "values": [30]} in entity["attributes"]
    assert entity["index"] == ["2025-02-03T04:05:06.789+00:00"]  # keyValues, as the user property said


def test_messages_we_cannot_use_are_kept_with_their_topic(feed):
    record = recorded("ngsi-ld/normalized.json")
    feed.publish("v2/acme/bad", b"{not json")
    feed.publish("nowhere", v2({"id": "R:lost", "type": "Robot", "x": 1}))  # no template, no tenant header
    feed.publish("ld", envelope({**record["headers"], "Ngsild-Tenant": "a", "Fiware-Service": "b"}, record["body"]))
    feed.publish("v2/acme/one", {"metadata": {"Fiware-ServicePath": "/two"}, "body": v2({"id": "R:p"})})
    feed.settled(feed.published)

    bad = rejected_on(feed, "v2/acme/bad")
    assert (bad["tenant"], bad["body"], bad["error"]) == ("acme", "{not json", "ParseError")
    lost = rejected_on(feed, "nowhere")
    assert lost["error"] == "UnknownTenant" and "TSDB_MQTT_DEFAULT_TENANT" in lost["description"]
    assert orjson.loads(lost["body"]) == v2({"id": "R:lost", "type": "Robot", "x": 1})
    both = rejected_on(feed, "ld")
    assert "conflicting tenant selectors" in both["description"] and both["tenant"] == "a,b"
    assert both["headers"]["Ngsild-Tenant"] == "a"  # the envelope's metadata, as the headers it stood for
    paths = rejected_on(feed, "v2/acme/one")
    assert "names service path '/one'" in paths["description"]


def test_a_message_over_the_body_limit_is_kept_truncated(client_factory, store_url, mosquitto):
    prefix, client = consuming(client_factory, store_url, mosquitto, max_body_bytes=2048, rejected_body_max_bytes=100)
    with client, Publisher(mosquitto.url) as publisher:
        feed = Feed(client, client.app, publisher, prefix)
        big = orjson.dumps(v2({"id": "R:big", "type": "Robot", "blob": "x" * 5000}))
        feed.publish("v2/acme/", big)
        feed.settled(1)
        row = rejected_on(feed, "v2/acme/")
        assert (row["error"], row["bodySize"], row["bodyTruncated"]) == ("PayloadTooLarge", len(big), True)
        assert row["body"].encode() == big[:100]


def test_the_default_tenant_setting(client_factory, store_url, mosquitto):
    prefix, client = consuming(client_factory, store_url, mosquitto, mqtt_default_tenant="Fallback")
    with client, Publisher(mosquitto.url) as publisher:
        feed = Feed(client, client.app, publisher, prefix)
        feed.publish("nowhere", v2({"id": "R:fb", "type": "Robot", "x": timed(1)}))
        feed.settled(1)
        assert feed.history("R:fb", "fallback")[0] == 200
