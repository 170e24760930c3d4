"""``POST /v2/notify``: where the broker's memory is written.

Orion never retries a notification, and counts any answer, 4xx and 5xx
included, as delivered. So a 200 is sent only after the samples are
committed, and a notification we cannot parse is kept in the rejected store
before its 400 goes out: nothing the broker sent us is silently dropped.
"""

from __future__ import annotations

import logging
from datetime import UTC, datetime

import orjson
from fastapi import APIRouter, Query, Request
from starlette.concurrency import run_in_threadpool
from starlette.responses import Response

from ..errors import ParseError, PayloadTooLarge, TsdbError, UnsupportedMediaType
from ..model import RejectedNotification
from ..ngsi import ValuesLayout, parse_notification
from ..security import redact_headers
from ..storage.base import AppendSamples, PutLayout, RecordRejected
from .handlers import internal_error
from .responses import JSON
from .tenancy import tenant_of

router = APIRouter(tags=["notify"])
log = logging.getLogger(__name__)

_OK_BODY = b'"Notification successfully processed"'
_JSON_TYPES = ("application/json", "application/ld+json")
# Parsing a big body on the event loop would stall every other request.
_PARSE_INLINE_MAX = 64 * 1024


NOTIFY_PATHS = frozenset({"/v2/notify", "/ngsi-ld/v1/notify"})
_JSON_HEADERS = [(b"content-type", b"application/json")]


@router.post("/v2/notify", summary="Receive an NGSIv2 or NGSI-LD notification")
async def notify(request: Request) -> Response:
    status, payload = await receive_notification(request)
    return Response(payload, status_code=status, media_type="application/json")


@router.post("/ngsi-ld/v1/notify", summary="Receive an NGSI-LD notification")
async def notify_ld(request: Request) -> Response:
    status, payload = await receive_notification(request)
    return Response(payload, status_code=status, media_type="application/json")


def is_notification(scope) -> bool:
    return scope["type"] == "http" and scope["method"] == "POST" and scope["path"] in NOTIFY_PATHS


async def serve_notification(app, scope, receive, send) -> None:
    """Serve a notify URL in front of the framework's middleware and routing
    stack, which costs more per request than parsing a notification. The
    behaviour is the routes' above (same function); only the overhead goes."""
    scope["app"] = app
    status, payload = await receive_notification(Request(scope, receive))
    await send({"type": "http.response.start", "status": status,
                "headers": [*_JSON_HEADERS, (b"content-length", str(len(payload)).encode())]})
    await send({"type": "http.response.body", "body": payload})


async def receive_notification(request: Request) -> tuple[int, bytes]:
    """Parse, store, then answer: ``(status, JSON body)``, errors in the NGSI shape."""
    try:
        await _receive(request)
    except TsdbError as exc:
        return exc.status, orjson.dumps(exc.body())
    except Exception:  # a bug: still answer in the NGSI shape
        return 500, orjson.dumps(internal_error("notification failed")[1])
    return 200, _OK_BODY


async def _receive(request: Request) -> None:
    state = request.app.state
    store = state.store
    received_at = datetime.now(UTC)
    body = b""
    try:
        _check_content_type(request)
        body = await _read_body(request, state.settings.max_body_bytes)
        layouts = store.values_layout
        if len(body) <= _PARSE_INLINE_MAX:
            entities = parse_notification(body, request.headers, received_at=received_at, values_layout=layouts)
        else:
            entities = await run_in_threadpool(
                parse_notification, body, request.headers, received_at=received_at, values_layout=layouts
            )
    except TsdbError as exc:
        if exc.status < 500:
            await _keep_rejected(request, store, received_at, exc, body)
        raise
    await store.write(AppendSamples(entities))


def _check_content_type(request: Request) -> None:
    media = request.headers.get("content-type", "").split(";", 1)[0].strip().lower()
    if media not in _JSON_TYPES:
        raise UnsupportedMediaType(
            f"notifications must be application/json or application/ld+json, not {media or 'missing'!r}"
        )


async def _read_body(request: Request, limit: int) -> bytes:
    declared = request.headers.get("content-length")
    if declared is not None and declared.isdigit() and int(declared) > limit:
        raise PayloadTooLarge(f"notification of {declared} bytes exceeds the {limit}-byte limit")
    chunks, size = [], 0
    async for chunk in request.stream():
        size += len(chunk)
        if size > limit:
            raise PayloadTooLarge(f"notification exceeds the {limit}-byte limit")
        chunks.append(chunk)
    return b"".join(chunks)


async def _keep_rejected(request, store, received_at: datetime, exc: TsdbError, body: bytes) -> None:
    try:
        tenant = tenant_of(request)
    except TsdbError:
        tenant = (request.headers.get("fiware-service") or "")[:200].lower()
    rejected = RejectedNotification(
        tenant=tenant,
        received_at=received_at,
        error=exc.error,
        description=exc.description,
        headers=orjson.dumps(redact_headers(request.headers, request.app.state.settings.api_key_header)).decode(),
        body=body,
    )
    await store.write(RecordRejected(rejected))


@router.get("/v2/notify/rejected", summary="Notifications we answered with 4xx, newest first")
def list_rejected(
    request: Request,
    limit: int = Query(100, ge=1, le=10_000),
    offset: int = Query(0, ge=0),
) -> JSON:
    return JSON(request.app.state.store.rejected(tenant_of(request), limit, offset))


@router.put(
    "/v2/notify/subscriptions/{subscription_id}",
    summary="Register the attribute list of a subscription that notifies in Orion's 'values' format",
)
async def put_layout(subscription_id: str, request: Request) -> JSON:
    tenant = tenant_of(request)
    try:
        doc = orjson.loads(await request.body())
    except orjson.JSONDecodeError as exc:
        raise ParseError(f"invalid JSON: {exc}") from None
    layout = layout_from_document(doc)
    await request.app.state.store.write(PutLayout(tenant, subscription_id, layout))
    return JSON(layout_document(layout), status_code=200)


@router.get("/v2/notify/subscriptions", summary="Registered 'values' layouts of this tenant")
def list_layouts(request: Request) -> JSON:
    layouts = request.app.state.store.layouts(tenant_of(request))
    return JSON({sub: layout_document(layout) for sub, layout in sorted(layouts.items())})


def layout_from_document(doc: object) -> ValuesLayout:
    """Accept our short form ``{"attrs": [...], "entityId", "entityType"}`` or a
    whole Orion subscription (``notification.attrs``, ``subject.entities``)."""
    if not isinstance(doc, dict):
        raise ParseError("expected a JSON object with 'attrs' or an Orion subscription")
    attrs, entity_id, entity_type = doc.get("attrs"), doc.get("entityId"), doc.get("entityType")
    notification, subject = doc.get("notification"), doc.get("subject")
    if attrs is None and isinstance(notification, dict):
        attrs = notification.get("attrs")
        entities = subject.get("entities") if isinstance(subject, dict) else None
        if isinstance(entities, list) and len(entities) == 1 and isinstance(entities[0], dict):
            entity_id = entities[0].get("id")
            entity_type = entities[0].get("type")
    if not isinstance(attrs, list) or not attrs or not all(isinstance(a, str) and a for a in attrs):
        raise ParseError("'attrs' must be a non-empty list of attribute names, in notification order")
    for name, value in (("entityId", entity_id), ("entityType", entity_type)):
        if value is not None and not isinstance(value, str):
            raise ParseError(f"'{name}' must be a string")
    if "id" not in attrs and not entity_id:
        raise ParseError("without an 'id' column in 'attrs', 'entityId' is required")
    return ValuesLayout(tuple(attrs), entity_id, entity_type)


def layout_document(layout: ValuesLayout) -> dict:
    return {"attrs": list(layout.attrs), "entityId": layout.entity_id, "entityType": layout.entity_type}
