"""``POST /v2/subscribe``: QuantumLeap's subscription helper, against a broker over HTTP.

Orion is not available here, so a small stand-in broker runs with uvicorn on
127.0.0.1: it keeps the subscriptions it is given per tenant (as Orion does,
201 + ``Location``), refuses a bad ``idPattern`` with Orion's error shape and,
when asked, notifies every subscription the way Orion would (``http`` or
``httpCustom`` with its headers, the subscription's tenant). The end-to-end
test runs tsdb-service itself with uvicorn too, so the notification crosses
real HTTP into a real store.
"""

from __future__ import annotations

import httpx
import pytest

from tests.support.server import free_port
from tests.support.serving import serving
from tests.support.standins import StandInBroker, served

QL = "http://tsdb-service:8668/v2"
LOCAL = "http://127.0.0.1:"  # the stand-in broker is on loopback: allowed by TSDB_SUBSCRIBE_BROKER_ALLOW
METADATA = ["dateCreated", "dateModified", "TimeInstant", "timestamp"]


@pytest.fixture(scope="module")
def broker():
    with served(StandInBroker()) as stand_in:
        yield stand_in


@pytest.fixture(scope="module")
def subscribing(client_factory, store_url_factory):
    with client_factory(store_url_factory("subscribe"), subscribe_broker_allow=LOCAL) as client:
        yield client


@pytest.fixture
def client(subscribing):
    """This module's client: one app per backend for every test, since
    ``POST /v2/subscribe`` stores nothing (it only talks to the broker)."""
    return subscribing


@pytest.fixture(autouse=True)
def _fresh_broker(broker):
    broker.subscriptions.clear()


def subscribe(client, broker, headers=None, **params):
    params = {"orionUrl": broker.url + "/v2", "quantumleapUrl": QL, **params}
    return client.post("/v2/subscribe", params=params, headers=headers or {})


def only_subscription(broker, tenant=("", "/")) -> dict:
    subs = broker.subscriptions.get(tenant, [])
    assert len(subs) == 1, broker.subscriptions
    sub = dict(subs[0])
    sub.pop("id")
    return sub


# --- what gets created -------------------------------------------------------------------------


def test_defaults_follow_everything(client, broker):
    r = subscribe(client, broker)
    assert r.status_code == 201, r.text
    sub_id = r.json()["subscriptionId"]
    assert r.headers["location"] == f"{broker.url}/v2/subscriptions/{sub_id}"
    expected = {
        "description": f"Created by tsdb-service {QL}.",
        "subject": {"entities": [{"idPattern": ".*"}]},
        "notification": {"http": {"url": f"{QL}/notify"}, "metadata": METADATA},
        "throttling": 1,
    }
    assert only_subscription(broker) == expected
    assert r.json() == {"subscriptionId": sub_id, "location": r.headers["location"], "subscription": expected}


def test_custom_parameters_under_the_request_tenant(client, broker):
    headers = {"Fiware-Service": "custom", "Fiware-ServicePath": "/custom"}
    r = subscribe(
        client,
        broker,
        headers,
        entityType="Room",
        idPattern="Room1",
        observedAttributes="temperature,pressure",
        notifiedAttributes="pressure",
        throttling="30",
    )
    assert r.status_code == 201, r.text
    assert broker.subscriptions.get(("", "/")) is None
    assert only_subscription(broker, ("custom", "/custom")) == {
        "description": f"Created by tsdb-service {QL}.",
        "subject": {
            "entities": [{"type": "Room", "idPattern": "Room1"}],
            "condition": {"attrs": ["temperature", "pressure"]},
        },
        "notification": {"http": {"url": f"{QL}/notify"}, "attrs": ["pressure"], "metadata": METADATA},
        "throttling": 30,
    }


@pytest.mark.parametrize(("observed", "notified"), [(None, "b"), ("a", None), ("a", "b")])
def test_attributes_overrides_observed_and_notified(client, broker, observed, notified):
    extra = {k: v for k, v in (("observedAttributes", observed), ("notifiedAttributes", notified)) if v}
    assert subscribe(client, broker, attributes="x, y", **extra).status_code == 201
    sub = only_subscription(broker)
    assert sub["subject"]["condition"] == {"attrs": ["x", "y"]}
    assert sub["notification"]["attrs"] == ["x", "y"]


def test_entity_id_wins_over_id_pattern(client, broker):
    assert subscribe(client, broker, entityId="e123", idPattern="e1.*").status_code == 201
    assert only_subscription(broker)["subject"]["entities"] == [{"id": "e123"}]


def test_time_index_attribute_is_sent_as_a_header(client, broker):
    assert subscribe(client, broker, timeIndexAttribute="measuredAt").status_code == 201
    assert only_subscription(broker)["notification"] == {
        "httpCustom": {"url": f"{QL}/notify", "headers": {"Fiware-TimeIndex-Attribute": "measuredAt"}},
        "metadata": [*METADATA, "measuredAt"],
    }


def test_zero_throttling_is_kept(client, broker):
    assert subscribe(client, broker, throttling="0").status_code == 201
    assert only_subscription(broker)["throttling"] == 0


def test_base_urls_without_version_get_v2(client, broker):
    r = client.post("/v2/subscribe", params={"orionUrl": broker.url, "quantumleapUrl": "http://tsdb:8668/"})
    assert r.status_code == 201, r.text
    assert only_subscription(broker)["notification"]["http"] == {"url": "http://tsdb:8668/v2/notify"}


# --- refusals ----------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "params",
    [
        {"quantumleapUrl": QL},
        {"orionUrl": "http://orion:1026/v2"},
        {"orionUrl": "blabla", "quantumleapUrl": QL},
        {"orionUrl": "ftp://orion/v2", "quantumleapUrl": QL},
        {"orionUrl": "http://orion:1026/v2", "quantumleapUrl": "http://:8668/v2"},
        {"orionUrl": "http://orion:99999/v2", "quantumleapUrl": QL},
        {"orionUrl": "http://orion:1026/v2?x=1", "quantumleapUrl": QL},
        {"orionUrl": "http://orion:1026/v2", "quantumleapUrl": QL, "throttling": "-1"},
        {"orionUrl": "http://orion:1026/v2", "quantumleapUrl": QL, "throttling": "soon"},
        {"orionUrl": "http://orion:1026/v2", "quantumleapUrl": QL, "entityType": "T" * 300},
    ],
)
def test_bad_parameters_are_400_before_any_broker_call(client, broker, params):
    r = client.post("/v2/subscribe", params=params)
    assert r.status_code == 400, r.text
    assert set(r.json()) == {"error", "description"}
    assert broker.subscriptions == {}


def test_bad_tenant_is_400(client, broker):
    r = subscribe(client, broker, {"Fiware-Service": "no spaces!"})
    assert r.status_code == 400 and r.json()["error"] == "BadRequest"
    r = subscribe(client, broker, {"Fiware-ServicePath": "relative"})
    assert r.status_code == 400
    assert broker.subscriptions == {}


def test_unreachable_broker_is_quantumleaps_400(client):
    orion = f"http://127.0.0.1:{free_port()}/v2"
    r = client.post("/v2/subscribe", params={"orionUrl": orion, "quantumleapUrl": QL})
    assert r.status_code == 400
    assert r.json()["error"] == "Bad Request"
    assert r.json()["description"].startswith(f"Orion is not reachable at {orion}: ")


# --- outbound rules: the client names the URL, so it may not aim us anywhere -----------------------


def test_a_broker_on_a_non_public_address_is_refused_unless_allowed(client_factory, store_url, broker):
    """Without TSDB_SUBSCRIBE_BROKER_ALLOW, loopback (and private, link-local,
    e.g. 169.254.169.254) brokers are never called, and the answer says
    nothing about what is there."""
    with client_factory(store_url) as client:
        for orion in (broker.url + "/v2", "http://169.254.169.254/v2", "http://10.0.0.1:1026/v2"):
            r = client.post("/v2/subscribe", params={"orionUrl": orion, "quantumleapUrl": QL})
            assert r.status_code == 400, r.text
            assert r.json()["description"] == (
                f"Orion is not reachable at {orion}: no answer (or the address is not allowed: "
                "TSDB_SUBSCRIBE_BROKER_ALLOW)"
            )
    assert broker.subscriptions == {}


def test_broker_calls_share_one_policy_and_its_bound(client, broker):
    """One outbound policy per app: its semaphore bounds the broker calls of
    all requests together, not of each request alone."""
    assert subscribe(client, broker).status_code == 201
    policy = client.app.state.subscribe_policy
    assert subscribe(client, broker, entityType="Room").status_code == 201
    assert client.app.state.subscribe_policy is policy


def test_a_redirecting_broker_is_not_followed(client, broker):
    r = client.post("/v2/subscribe", params={"orionUrl": broker.url + "/moved/v2", "quantumleapUrl": QL})
    assert r.status_code == 502 and "307" in r.json()["description"]
    assert broker.subscriptions == {}


def test_broker_refusal_is_passed_on(client, broker):
    r = subscribe(client, broker, idPattern="(")
    assert (r.status_code, r.json()) == (
        400,
        {"error": "BadRequest", "description": "Invalid regex for entity idPattern"},
    )


def test_not_a_broker_gets_a_hint(client, broker):
    r = client.post("/v2/subscribe", params={"orionUrl": broker.url + "/elsewhere/v2", "quantumleapUrl": QL})
    assert r.status_code == 404
    assert r.json()["error"] == "BadRequest"
    assert "answered 404" in r.json()["description"] and "orionUrl" in r.json()["description"]


def test_broker_failure_is_502(client, broker):
    r = client.post("/v2/subscribe", params={"orionUrl": broker.url + "/broken/v2", "quantumleapUrl": QL})
    assert r.status_code == 502
    assert r.json()["error"] == "BadGateway" and "500" in r.json()["description"]
    assert "database down" not in r.text


# --- end to end: the broker notifies what it was subscribed to ------------------------------------


def test_subscription_feeds_the_service(app_factory, store_url, broker):
    tenant = {"Fiware-Service": "Building", "Fiware-ServicePath": "/floor1"}
    with serving(app_factory(store_url, subscribe_broker_allow=LOCAL)) as service:
        r = httpx.post(
            f"{service}/v2/subscribe",
            headers=tenant,
            timeout=10,
            params={
                "orionUrl": broker.url + "/v2",
                "quantumleapUrl": service + "/v2",
                "entityType": "Room",
                "notifiedAttributes": "temperature,measuredAt",
                "timeIndexAttribute": "measuredAt",
            },
        )
        assert r.status_code == 201, r.text
        entity = {
            "id": "Room1",
            "type": "Room",
            "temperature": {"type": "Number", "value": 21.5, "metadata": {}},
            "pressure": {"type": "Number", "value": 1000, "metadata": {}},
            "measuredAt": {"type": "DateTime", "value": "2024-03-01T08:00:00.000Z", "metadata": {}},
        }
        assert broker.notify(entity) == [200]
        got = httpx.get(f"{service}/v2/entities/Room1", headers=tenant, timeout=10).json()
    assert got["index"] == ["2024-03-01T08:00:00.000+00:00"]
    assert [a["attrName"] for a in got["attributes"]] == ["measuredAt", "temperature"]
