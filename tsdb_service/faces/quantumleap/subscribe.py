"""``POST /v2/subscribe``: QuantumLeap's (<= 0.8) subscription helper.

A client names the broker (``orionUrl``), where the broker reaches us
(``quantumleapUrl``) and what to follow; we create the Orion subscription
that makes the broker notify ``{quantumleapUrl}/notify``, under the
request's ``Fiware-Service`` and ``Fiware-ServicePath``. The subscription is
the one QuantumLeap built:

* ``subject.entities``: one entry with ``type`` (``entityType``) and ``id``
  (``entityId``), else ``idPattern`` (default ``.*``);
* ``attributes`` sets both ``subject.condition.attrs`` and
  ``notification.attrs``; otherwise ``observedAttributes`` sets the first and
  ``notifiedAttributes`` the second;
* ``notification.metadata``: ``dateCreated``, ``dateModified``,
  ``TimeInstant``, ``timestamp`` (and ``timeIndexAttribute``), the metadata
  our time index reads;
* ``timeIndexAttribute`` makes it an ``httpCustom`` notification carrying
  ``Fiware-TimeIndex-Attribute``;
* ``throttling`` in seconds, 1 when not given.

The broker's own answer decides ours: its 201 becomes ours (with the
subscription's URL at the broker in ``Location``); its 4xx is passed on; an
unreachable broker is QuantumLeap's ``400 Orion is not reachable``; a 5xx or
anything unexpected is ``502``.

The request makes this service send an HTTP request to a URL the client
chooses, so it goes out under the outbound rules (``http.outbound``): a
broker whose host resolves to a loopback, private or otherwise non-public
address is refused unless its URL starts with a prefix of
``TSDB_SUBSCRIBE_BROKER_ALLOW`` (a deliberate difference from QuantumLeap,
which posts anywhere); no redirect is followed; the whole exchange has a
deadline and the answer a byte bound; and a refusal or failure reads the
same to the client ("not reachable"), whatever the network said.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from urllib.parse import urlsplit

import orjson
from fastapi import APIRouter, Request

from tsdb_service.broker.subscriptions import BrokerAnswer
from tsdb_service.core.errors import BadRequest, TsdbError
from tsdb_service.core.urlprefix import url_prefixes
from tsdb_service.faces.quantumleap import openapi as ql_oa
from tsdb_service.http.outbound import FetchFailed, FetchPolicy, post
from tsdb_service.http.responses import JSON
from tsdb_service.http.tenancy import tenant_of
from tsdb_service.parse.request_context import service_paths

log = logging.getLogger(__name__)

router = APIRouter(tags=["subscribe"])

METADATA = ("dateCreated", "dateModified", "TimeInstant", "timestamp")
TIME_INDEX_HEADER = "Fiware-TimeIndex-Attribute"
DEFAULT_THROTTLING = 1
_MAX_URL = 2048
_MAX_NAME = 256
_MAX_ERROR_TEXT = 500
BROKER_DEADLINE = 10.0  # seconds for the whole exchange with the broker
BROKER_ANSWER_BYTES = 64 * 1024  # a subscription's answer is a few hundred bytes


@router.post(
    "/v2/subscribe",
    status_code=201,
    summary="Create the Orion subscription that feeds this service",
    **ql_oa.SUBSCRIBE_SPEC,
)
async def subscribe(request: Request) -> JSON:
    """Everything is checked before the broker is called; the call waits on
    the event loop (a slow broker costs a coroutine, not a thread)."""
    params = request.query_params
    orion = _base_url(params.get("orionUrl"), "orionUrl")
    document = build_subscription(_base_url(params.get("quantumleapUrl"), "quantumleapUrl"), params)
    answer = await _send(orion + "/subscriptions", document, _broker_headers(request), _broker_policy(request))
    return _answer(orion, document, answer)


def _broker_policy(request: Request) -> FetchPolicy:
    """The app's outbound policy for brokers, made on first use and kept, so
    its semaphore bounds the broker calls of every request together."""
    state = request.app.state
    policy = getattr(state, "subscribe_policy", None)
    if policy is None:
        policy = state.subscribe_policy = FetchPolicy(
            deadline=BROKER_DEADLINE,
            max_bytes=BROKER_ANSWER_BYTES,
            max_redirects=0,
            allow=url_prefixes(state.settings.subscribe_broker_allow),
            accept="application/json",
        )
    return policy


async def _send(url: str, document: dict, headers: dict[str, str], policy: FetchPolicy) -> BrokerAnswer:
    """POST the subscription under the outbound rules; why it failed goes
    to the log only (the client learns nothing about our network)."""
    try:
        answer = await post(url, orjson.dumps(document), headers, policy)
    except FetchFailed as exc:
        log.warning("POST /v2/subscribe: the broker was not reached: %s", exc)
        return BrokerAnswer(None, problem="no answer (or the address is not allowed: TSDB_SUBSCRIBE_BROKER_ALLOW)")
    text = answer.body.decode("utf-8", "replace")
    return BrokerAnswer(answer.status, answer.reason, answer.headers.get("location", ""), text)


def build_subscription(service_url: str, params: Mapping[str, str]) -> dict:
    """The Orion subscription QuantumLeap's helper made, from the query parameters."""
    entity_type = _name(params, "entityType")
    entity_id = _name(params, "entityId")
    entity: dict[str, str] = {"type": entity_type} if entity_type else {}
    if entity_id:
        entity["id"] = entity_id
    else:
        entity["idPattern"] = _name(params, "idPattern") or ".*"
    attributes = _names(params, "attributes")
    observed = attributes or _names(params, "observedAttributes")
    notified = attributes or _names(params, "notifiedAttributes")
    time_index = _name(params, "timeIndexAttribute")

    subject: dict = {"entities": [entity]}
    if observed:
        subject["condition"] = {"attrs": observed}
    notify_url = service_url + "/notify"
    if time_index:
        target = {"httpCustom": {"url": notify_url, "headers": {TIME_INDEX_HEADER: time_index}}}
    else:
        target = {"http": {"url": notify_url}}
    notification: dict = {**target}
    if notified:
        notification["attrs"] = notified
    notification["metadata"] = [*METADATA, *([time_index] if time_index and time_index not in METADATA else [])]
    return {
        "description": f"Created by tsdb-service {service_url}.",
        "subject": subject,
        "notification": notification,
        "throttling": _throttling(params.get("throttling")),
    }


# --- parameters ------------------------------------------------------------------------------


def _base_url(raw: str | None, name: str) -> str:
    """An absolute http(s) URL with the API version: ``http://host:port/v2``.
    A bare ``http://host:port`` gets ``/v2``, the only version either side has."""
    if raw is None or not raw.strip():
        raise BadRequest(f"{name} is required: the base URL with the API version, e.g. http://orion:1026/v2")
    text = raw.strip()
    parts = urlsplit(text) if len(text) <= _MAX_URL else None
    if parts is None or parts.scheme not in ("http", "https") or not parts.hostname or parts.query or parts.fragment:
        raise BadRequest(f"{name} must be an absolute http(s) URL such as http://orion:1026/v2, not {raw[:120]!r}")
    try:
        parts.port  # noqa: B018 - raises on a bad port
    except ValueError:
        raise BadRequest(f"{name} has a bad port: {raw[:120]!r}") from None
    base = text.rstrip("/")
    return base if parts.path.strip("/") else base + "/v2"


def _name(params: Mapping[str, str], key: str) -> str | None:
    value = (params.get(key) or "").strip()
    if not value:
        return None
    if len(value) > _MAX_NAME:
        raise BadRequest(f"{key} is longer than {_MAX_NAME} characters")
    return value


def _names(params: Mapping[str, str], key: str) -> list[str]:
    """A comma list; empty items are dropped, the order is kept."""
    raw = params.get(key) or ""
    names = list(dict.fromkeys(part.strip() for part in raw.split(",") if part.strip()))
    for name in names:
        if len(name) > _MAX_NAME:
            raise BadRequest(f"{key} lists a name longer than {_MAX_NAME} characters")
    return names


def _throttling(raw: str | None) -> int:
    if raw is None or not raw.strip():
        return DEFAULT_THROTTLING
    text = raw.strip()
    if not text.isdigit() or len(text) > 9:
        raise BadRequest(f"throttling must be a non-negative number of seconds, not {raw[:40]!r}")
    return int(text)


def _broker_headers(request: Request) -> dict[str, str]:
    """The tenancy of the request, forwarded as given (after checking it)."""
    headers = {"Content-Type": "application/json"}
    service = (request.headers.get("fiware-service") or "").strip()
    if service:
        tenant_of(request)  # a tenant we would refuse to store is refused here too
        headers["Fiware-Service"] = service
    path = (request.headers.get("fiware-servicepath") or "").strip()
    if path:
        service_paths(path)
        headers["Fiware-ServicePath"] = path
    return headers


# --- the broker's answer -------------------------------------------------------------------------


def _answer(orion: str, document: dict, answer: BrokerAnswer) -> JSON:
    if answer.status is None:
        raise BadRequest(f"Orion is not reachable at {orion}: {answer.problem}", error="Bad Request")
    if answer.created:
        location = _absolute(orion, answer.location)
        body = {"subscriptionId": answer.subscription_id, "location": location, "subscription": document}
        return JSON(body, status_code=201, headers={"Location": location} if location else None)
    if 400 <= answer.status < 500:
        raise TsdbError(**_broker_error(orion, answer), status=answer.status)
    raise TsdbError(
        f"the broker at {orion} answered {answer.status} {answer.reason} to the subscription",
        error="BadGateway",
        status=502,
    )


def _broker_error(orion: str, answer: BrokerAnswer) -> dict[str, str]:
    """The broker's own NGSI error when it sent one; else what happened, with
    a hint for the usual mistake (a URL that is not the broker's API)."""
    try:
        doc = orjson.loads(answer.text) if answer.text else None
    except orjson.JSONDecodeError:
        doc = None
    if isinstance(doc, dict) and isinstance(doc.get("error"), str):
        description = doc.get("description")
        text = description if isinstance(description, str) else ""
        return {"error": doc["error"][:100], "description": text[:_MAX_ERROR_TEXT]}
    hint = " (is orionUrl the broker's API base, e.g. http://orion:1026/v2?)" if answer.status in (404, 405) else ""
    return {
        "error": "BadRequest",
        "description": f"the broker at {orion} answered {answer.status} {answer.reason} to the subscription{hint}",
    }


def _absolute(orion: str, location: str) -> str:
    """Orion answers ``Location: /v2/subscriptions/<id>``, relative to itself."""
    if not location or "://" in location:
        return location
    parts = urlsplit(orion)
    return f"{parts.scheme}://{parts.netloc}{location if location.startswith('/') else '/' + location}"
