"""Orion subscriptions that make a real broker feed us, and recorded examples.

The payloads are built here, not read from ``notifications/``, so that
``tsdb-service subscribe`` works from an installed wheel; ``notifications/``
holds the same documents written out by ``tsdb-service notifications build``
(a test keeps the two identical).
"""

from __future__ import annotations

import ipaddress
import itertools
import random
import socket
from collections.abc import Callable
from dataclasses import dataclass, replace
from datetime import UTC, datetime
from pathlib import Path
from urllib.parse import urlsplit

import httpx
import orjson

from tsdb_service.broker.listing import list_all
from tsdb_service.usecases import orion
from tsdb_service.usecases.base import Simulator
from tsdb_service.usecases.registry import SIMULATORS

# Where Orion notifies us inside docker-compose.yml's network (the recorded
# subscriptions of notifications/ use it too); elsewhere see default_notify_url.
COMPOSE_NOTIFY_URL = "http://tsdb-service:8668/v2/notify"
PORT = 8668
# A documentation address (RFC 5737): a UDP socket "connected" to it tells
# which local address the default route uses, without sending anything.
_ANY_REMOTE = "192.0.2.1"

_EXAMPLE_START = datetime(2025, 6, 2, 9, 0, tzinfo=UTC)


def _data(entity: dict, attr: str) -> object:
    return entity.get(attr, {}).get("value", {}).get("data")


# The recorded example of each use case: its first notification that shows
# the interesting part (an operator's cmd_vel, a door opening, a drone in flight).
_EXAMPLE_WANTED = {
    "lawnmower": lambda e: "cmd_vel" in e and _data(e, "navigationState") == 5,
    "warehouse": lambda e: _data(e, "doorCommand") == 1 and _data(e, "doorState") == 2,
    "drone": lambda e: _data(e, "missionState") == 2,
}


def default_notify_url(broker: str, port: int = PORT, path: str = "/v2/notify") -> str:
    """Where the broker at ``broker`` can reach a tsdb-service running on
    this machine: this machine's address on the route to the broker. A
    broker on this machine itself (``localhost``) often runs in a container,
    where ``localhost`` is the container: then the machine's address on its
    default route, which a container reaches as well as a local process.
    The host name when the machine has no route at all."""
    host = urlsplit(broker).hostname or "localhost"
    address = _local_address(host)
    if address is None or ipaddress.ip_address(address).is_loopback:
        address = _local_address(_ANY_REMOTE)
    if address is None:
        address = socket.gethostname()
    elif ":" in address:
        address = f"[{address}]"
    return f"http://{address}:{port}{path}"


def _local_address(host: str) -> str | None:
    """The local address a datagram to ``host`` would leave from (nothing is sent)."""
    try:
        family, _, _, _, target = socket.getaddrinfo(host, 9, type=socket.SOCK_DGRAM)[0]
        with socket.socket(family, socket.SOCK_DGRAM) as probe:
            probe.connect(target)
            return str(probe.getsockname()[0]).split("%")[0]
    except (OSError, UnicodeError):
        return None


def subscription(sim: Simulator, notify_url: str = COMPOSE_NOTIFY_URL) -> dict:
    """The NGSIv2 subscription for one use case: every change of its entities,
    the whole entity, normalized, with the IoT Agent's TimeInstant metadata."""
    return {
        "description": f"tsdb-service: history of the {sim.title}",
        "subject": {
            "entities": [{"idPattern": pattern, "type": entity_type} for pattern, entity_type in sim.subjects],
        },
        "notification": {
            "http": {"url": notify_url},
            "attrsFormat": "normalized",
            "metadata": ["TimeInstant"],
            "onlyChangedAttrs": False,
        },
        "throttling": 0,
    }


def broker_headers(sim: Simulator) -> dict[str, str]:
    """The tenancy headers a subscription must be created under."""
    return {
        "Content-Type": "application/json",
        "Fiware-Service": sim.tenancy.service,
        "Fiware-ServicePath": sim.tenancy.service_path,
    }


def ld_subscription(sim: Simulator, notify_url: str) -> dict:
    """The NGSI-LD subscription for one use case (Orion-LD): the same entities,
    normalized, to ``/ngsi-ld/v1/notify``. NGSI-LD has no service paths, so
    Orion-LD sends the use case's as a ``Fiware-ServicePath`` header
    (``receiverInfo``): the history lands where the NGSIv2 feed puts it, and
    the dashboards and the explorer find it there."""
    return {
        "type": "Subscription",
        "description": f"tsdb-service: history of the {sim.title}",
        "entities": [{"idPattern": pattern, "type": entity_type} for pattern, entity_type in sim.subjects],
        "notification": {
            "format": "normalized",
            "endpoint": {
                "uri": notify_url,
                "accept": "application/json",
                "receiverInfo": [{"key": "Fiware-ServicePath", "value": sim.tenancy.service_path}],
            },
        },
    }


def ld_broker_headers(sim: Simulator) -> dict[str, str]:
    """The tenant an NGSI-LD subscription or update is made in (no @context: the core one)."""
    return {"Content-Type": "application/json", "NGSILD-Tenant": sim.tenancy.service}


@dataclass(frozen=True, slots=True)
class BrokerApi:
    """Where and how a subscription is made on a broker, per API."""

    name: str
    subscriptions_path: str
    notify_path: str  # ours, where the broker sends notifications
    document: Callable[[Simulator, str], dict]
    headers: Callable[[Simulator], dict[str, str]]


NGSIV2 = BrokerApi("NGSIv2", "/v2/subscriptions", "/v2/notify", subscription, broker_headers)
NGSI_LD = BrokerApi("NGSI-LD", "/ngsi-ld/v1/subscriptions", "/ngsi-ld/v1/notify", ld_subscription, ld_broker_headers)


# --- over MQTT (issue 31; docs/mqtt.md) ---------------------------------------------------

# The topic our MQTT consumer reads tenant and service path from by default
# (TSDB_MQTT_TOPIC_TEMPLATE); Orion's mqttCustom fills the macros in.
MQTT_TOPIC = "tsdb/${service}${servicePath}"
_LD_MACROS = ("${service}", "${servicePath}")


def mqtt_subscription(sim: Simulator, broker: str, topic: str = MQTT_TOPIC) -> dict:
    """``subscription``, notifying over MQTT: Orion publishes each
    notification (the same body, no headers) to ``broker`` at QoS 1, on
    ``topic`` with its macros filled in (``mqttCustom``; a topic without
    macros works too)."""
    document = subscription(sim)
    notification = document["notification"]
    del notification["http"]
    notification["mqttCustom"] = {"url": broker.rstrip("/"), "topic": topic, "qos": 1}
    return document


def ld_mqtt_subscription(sim: Simulator, broker: str, topic: str = MQTT_TOPIC) -> dict:
    """``ld_subscription``, notifying over MQTT (Orion-LD): the endpoint is
    ``broker`` with the topic as its path, at QoS 1. Orion-LD has no topic
    macros: ``${service}`` and ``${servicePath}`` are filled in here, with
    the use case's tenant and service path (which Orion-LD's envelope also
    says, in its ``metadata``)."""
    document = ld_subscription(sim, broker)
    endpoint = document["notification"]["endpoint"]
    endpoint["uri"] = f"{broker.rstrip('/')}/{topic_of(sim, topic)}"
    endpoint["notifierInfo"] = [{"key": "MQTT-QoS", "value": "1"}]
    return document


def topic_of(sim: Simulator, topic: str) -> str:
    """``topic`` with the use case's tenant and service path filled in, as
    Orion would publish its notifications; ValueError for any other macro
    (Orion-LD fills in none)."""
    filled = topic.replace("${service}", sim.tenancy.service.lower()).replace(
        "${servicePath}", sim.tenancy.service_path
    )
    if "${" in filled:
        raise ValueError(f"Orion-LD fills in no topic macros, and only {' and '.join(_LD_MACROS)} can be done here")
    return filled


def mqtt_api(ld: bool, topic: str = MQTT_TOPIC) -> BrokerApi:
    """The API to subscribe with so the broker notifies over MQTT (the
    'notify URL' it is given is then the MQTT broker's URL): the HTTP one
    with the MQTT subscription document."""
    base, document = (NGSI_LD, ld_mqtt_subscription) if ld else (NGSIV2, mqtt_subscription)
    return replace(base, name=f"{base.name} over MQTT", document=lambda sim, broker: document(sim, broker, topic))


@dataclass(frozen=True, slots=True)
class BrokerAnswer:
    """What a broker answered to ``POST /v2/subscriptions``; ``status`` is
    None when it could not be reached (``problem`` says why)."""

    status: int | None
    reason: str = ""
    location: str = ""
    text: str = ""
    problem: str = ""

    @property
    def created(self) -> bool:
        return self.status == 201

    @property
    def subscription_id(self) -> str:
        return self.location.rstrip("/").rsplit("/", 1)[-1] if self.location else ""


def send_subscription(url: str, document: dict, headers: dict[str, str], timeout: float = 10.0) -> BrokerAnswer:
    """POST a subscription to a broker's ``.../v2/subscriptions`` URL.

    Shared by ``tsdb-service subscribe`` and ``POST /v2/subscribe``. Redirects
    are not followed: a subscription goes to the URL the operator named."""
    try:
        response = httpx.post(url, content=orjson.dumps(document), headers=headers, timeout=timeout)
    except httpx.HTTPError as exc:
        return BrokerAnswer(None, problem=f"{type(exc).__name__}: {exc}")
    return BrokerAnswer(
        response.status_code, response.reason_phrase, response.headers.get("location", ""), response.text
    )


def post_subscription(
    broker: str, sim: Simulator, notify_url: str, timeout: float = 10.0, api: BrokerApi = NGSIV2
) -> tuple[bool, str]:
    """Create the subscription on a broker; (created?, what the broker answered)."""
    url = broker.rstrip("/") + api.subscriptions_path
    answer = send_subscription(url, api.document(sim, notify_url), api.headers(sim), timeout)
    if answer.status is None:
        return False, f"could not reach {url}: {answer.problem}"
    if answer.created:
        sub_id = answer.subscription_id or "?"
        return True, f"201 Created: subscription {sub_id} ({answer.location}) on tenant {sim.tenancy.service!r}"
    return False, f"{answer.status} {answer.reason}: {answer.text.strip()[:500]}"


def list_subscriptions(
    broker: str, headers: dict[str, str], timeout: float = 10.0, path: str = NGSIV2.subscriptions_path
) -> tuple[list[dict] | None, str]:
    """Every subscription the broker has for the tenant and service path of
    ``headers``: ``(subscriptions, "")``, or ``(None, why)`` when it could not
    tell. Follows Orion's paging (20 a page by default, at most 1000;
    ``Fiware-Total-Count``, Orion-LD's ``NGSILD-Results-Count``, else short
    pages: ``broker.listing``)."""
    url = broker.rstrip("/") + path
    tenancy = {k: v for k, v in headers.items() if k.lower().startswith(("fiware-", "ngsild-"))}
    return list_all(url, {"options": "count", "count": "true"}, tenancy, "subscriptions", timeout)


def notify_url_of(document: dict) -> str | None:
    """Where a subscription sends its notifications (NGSIv2 ``http`` or
    ``httpCustom``, NGSI-LD ``endpoint``; over MQTT, NGSIv2 ``mqtt`` or
    ``mqttCustom``: the broker's URL and the topic)."""
    notification = document.get("notification")
    if not isinstance(notification, dict):
        return None
    for key, field in (("http", "url"), ("httpCustom", "url"), ("endpoint", "uri")):
        target = notification.get(key)
        if isinstance(target, dict) and isinstance(target.get(field), str):
            return target[field]
    for key in ("mqtt", "mqttCustom"):
        target = notification.get(key)
        if isinstance(target, dict) and isinstance(target.get("url"), str):
            return f"{target['url'].rstrip('/')} topic {target.get('topic')}"
    return None


def _selectors(document: dict) -> frozenset[tuple]:
    subject = document.get("subject")
    entities = subject.get("entities") if isinstance(subject, dict) else document.get("entities")
    return (
        frozenset(
            (e.get("id"), e.get("idPattern"), e.get("type"), e.get("typePattern"))
            for e in entities
            if isinstance(e, dict)
        )
        if isinstance(entities, list)
        else frozenset()
    )


def equivalent(existing: dict, wanted: dict) -> bool:
    """Would ``existing`` feed the same notify URL with the same entities as
    ``wanted``? Then creating ``wanted`` would store every sample twice."""
    return notify_url_of(existing) == notify_url_of(wanted) and _selectors(existing) == _selectors(wanted)


def ensure_subscription(
    broker: str, sim: Simulator, notify_url: str, timeout: float = 10.0, force: bool = False, api: BrokerApi = NGSIV2
) -> tuple[bool, str]:
    """Create the subscription unless the broker already has an equivalent
    one for the use case's tenant and service path (``force``: create
    anyway). ``(ok?, what happened)``; a broker whose subscriptions cannot
    be listed is not subscribed to (unless ``force``): running twice must
    never double the history."""
    if force:
        return post_subscription(broker, sim, notify_url, timeout, api)
    existing, problem = list_subscriptions(broker, api.headers(sim), timeout, api.subscriptions_path)
    if existing is None:
        # --force only helps a broker that answers but cannot list; one that cannot be reached gets nothing either way.
        hint = "" if problem.startswith("could not reach") else " (--force creates without checking)"
        return False, f"{problem}; nothing created{hint}"
    wanted = api.document(sim, notify_url)
    same = next((sub for sub in existing if equivalent(sub, wanted)), None)
    if same is None:
        return post_subscription(broker, sim, notify_url, timeout, api)
    tenancy = f"tenant {sim.tenancy.service!r} {sim.tenancy.service_path}"
    return True, (
        f"already subscribed: subscription {same.get('id', '?')} (status {same.get('status', 'unknown')}) "
        f"on {tenancy} notifies {notify_url}; nothing created (--force creates another)"
    )


def example_notification(sim: Simulator) -> tuple[dict[str, str], dict]:
    """A notification from a fixed-seed run, with the headers a broker at
    ``tsdb-service:8668`` would send along (including those libcurl adds)."""
    wire = random.Random(f"example:{sim.name}:orion")
    emissions = sim.emissions(_EXAMPLE_START, random.Random(f"example:{sim.name}"))
    wanted = _EXAMPLE_WANTED[sim.name]
    chosen = next(e for e in itertools.islice(emissions, 100_000) if wanted(e.entity))
    body_bytes = orion.notification_body(orion.subscription_id(wire), chosen.entity)
    headers = {"Host": "tsdb-service:8668"}
    headers.update(orion.notification_headers(sim.tenancy.service, sim.tenancy.service_path, orion.correlator(wire)))
    headers["Content-Length"] = str(len(body_bytes))
    return headers, orjson.loads(body_bytes)


def write_examples(root: Path) -> list[Path]:
    """Write ``notifications/<use case>/`` for every use case; returns the files written."""
    written = []
    for name, sim in SIMULATORS.items():
        folder = root / name
        folder.mkdir(parents=True, exist_ok=True)
        headers, body = example_notification(sim)
        documents = {
            "subscription.json": subscription(sim),
            "subscription.headers.json": broker_headers(sim),
            "notification.json": body,
            "notification.headers.json": headers,
        }
        for filename, document in documents.items():
            path = folder / filename
            path.write_bytes(dumps(document))
            written.append(path)
    return written


def dumps(document: object) -> bytes:
    """Pretty, stable JSON with a final newline, for files people read and diff."""
    return orjson.dumps(document, option=orjson.OPT_INDENT_2) + b"\n"
