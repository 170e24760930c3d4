"""``POST /v2/notify``: where the broker's memory is written.

Orion never retries a notification, and counts any answer, 4xx and 5xx
included, as delivered. So a 200 is sent only after the samples are
committed, and a notification we cannot parse, or that the database
refuses for its content (``NotStorable``, 422), is kept in the rejected
store before its 4xx goes out: nothing the broker sent us is silently
dropped.
"""

from __future__ import annotations

import logging
from collections.abc import AsyncIterator, Iterator, Mapping
from datetime import UTC, datetime
from functools import partial
from typing import Any

import orjson
from fastapi import APIRouter, Query, Request
from starlette.requests import ClientDisconnect
from starlette.responses import Response

from tsdb_service.core.credentials import redact_headers
from tsdb_service.core.errors import ParseError, PayloadTooLarge, TsdbError, UnsupportedMediaType
from tsdb_service.core.model import RejectedNotification
from tsdb_service.core.timepaths import parse_time_paths
from tsdb_service.http import openapi as oa
from tsdb_service.http.errors import REQUEST_ID_HEADER, internal_error
from tsdb_service.http.responses import JSON
from tsdb_service.http.store import app_store, reads_store, store_of
from tsdb_service.http.tenancy import require_every_tenant, tenant_header, tenant_of
from tsdb_service.ingest import openapi as notify_oa
from tsdb_service.parse import ValuesLayout, parse_notification
from tsdb_service.parse.names import ID_RULE, RULE, id_problem, name_problem
from tsdb_service.parse.request_context import MAX_INT_PARAM
from tsdb_service.write.ops import AppendSamples, PutLayout, RecordRejected

router = APIRouter(tags=["notify"])
log = logging.getLogger(__name__)

_OK_BODY = b'"Notification successfully processed"'
_DISCONNECTED = b'{"error":"ClientDisconnected","description":"the client disconnected before sending the whole body"}'
# Parsing a big body on the event loop would stall every other request.
_PARSE_INLINE_MAX = 64 * 1024
# A body over the limit without a Content-Length is counted (not kept) up to
# this many times the limit, then the request is answered anyway.
_DRAIN_FACTOR = 64

NOTIFY_PATHS = frozenset({"/v2/notify", "/ngsi-ld/v1/notify"})
_JSON_HEADERS = [(b"content-type", b"application/json")]


@router.post("/v2/notify", summary="Receive an NGSIv2 or NGSI-LD notification", **notify_oa.NOTIFY)
async def notify(request: Request) -> Response:
    status, payload, headers = await receive_notification(request)
    return Response(payload, status_code=status, headers=headers, media_type="application/json")


@router.post("/ngsi-ld/v1/notify", summary="Receive an NGSI-LD notification", **notify_oa.NOTIFY)
async def notify_ld(request: Request) -> Response:
    status, payload, headers = await receive_notification(request)
    return Response(payload, status_code=status, headers=headers, media_type="application/json")


def is_notification(scope) -> bool:
    return scope["type"] == "http" and scope["method"] == "POST" and scope["path"] in NOTIFY_PATHS


async def serve_notification(app, scope, receive, send) -> None:
    """Serve a notify URL in front of the framework's middleware and routing
    stack, which costs more per request than parsing a notification. The
    behaviour is the routes' above (same function); only the overhead goes."""
    scope["app"] = app
    status, payload, extra = await _answer(_Incoming(app, scope, receive))
    headers = [*_JSON_HEADERS, (b"content-length", str(len(payload)).encode())]
    if extra:
        headers += [(name.lower().encode(), value.encode()) for name, value in extra.items()]
    await send({"type": "http.response.start", "status": status, "headers": headers})
    await send({"type": "http.response.body", "body": payload})


async def receive_notification(request: Request) -> tuple[int, bytes, dict[str, str] | None]:
    """Parse, store, then answer: ``(status, JSON body, extra headers)``, errors in the NGSI shape.
    The body is read off ``request.receive``: nothing may have read it before."""
    return await _answer(_Incoming(request.app, request.scope, request.receive, request))


class _Headers(Mapping[str, str]):
    """A request's headers as Starlette's ``Headers`` reads them (names and
    values decoded as latin-1; ``get`` the first of a name, ``items`` every
    pair, repeats included), decoded once: the parser, the media type check
    and the rejected store each read them."""

    __slots__ = ("_pairs",)

    def __init__(self, raw: list[tuple[bytes, bytes]]):
        self._pairs = [(name.decode("latin-1"), value.decode("latin-1")) for name, value in raw]

    def __getitem__(self, key: str) -> str:
        key = key.lower()
        for name, value in self._pairs:
            if name == key:
                return value
        raise KeyError(key)

    def get(self, key: str, default: Any = None) -> Any:
        key = key.lower()
        for name, value in self._pairs:
            if name == key:
                return value
        return default

    def items(self) -> list[tuple[str, str]]:  # type: ignore[override]
        return self._pairs

    def __iter__(self) -> Iterator[str]:
        return iter([name for name, _ in self._pairs])

    def __len__(self) -> int:
        return len(self._pairs)


class _Incoming:
    """One notification being received: the ASGI scope, its headers decoded
    once, the body read straight off ``receive``. A Starlette ``Request`` is
    made only for the rare answers that need one (a refused notification's
    tenant, which authorises the caller)."""

    __slots__ = ("_request", "app", "headers", "receive", "scope")

    def __init__(self, app, scope, receive, request: Request | None = None):
        self.app = app
        self.scope = scope
        self.receive = receive
        self.headers = _Headers(scope["headers"])
        self._request = request

    def request(self) -> Request:
        if self._request is None:
            self._request = Request(self.scope, self.receive)
        return self._request

    def peer(self) -> str:
        client = self.scope.get("client")
        return f"{client[0]}:{client[1]}" if client else "a client"


async def _answer(incoming: _Incoming) -> tuple[int, bytes, dict[str, str] | None]:
    try:
        await _receive(incoming)
    except TsdbError as exc:
        return exc.status, orjson.dumps(exc.body()), None
    except ClientDisconnect:  # nothing was stored and nobody is left to answer: one line, no traceback
        log.warning(
            "notification from %s abandoned: the client disconnected before sending the whole body "
            "(Content-Length %s); nothing was stored",
            incoming.peer(),
            incoming.headers.get("content-length"),
        )
        return 400, _DISCONNECTED, None
    except Exception:  # a bug: answered as api.handlers answers any other 500 (body and request id header)
        request_id, body = internal_error("notification failed")
        return 500, orjson.dumps(body), {REQUEST_ID_HEADER: request_id}
    return 200, _OK_BODY, None


async def _receive(incoming: _Incoming) -> None:
    state = incoming.app.state
    store = app_store(incoming.app)
    settings = state.settings
    received_at = datetime.now(UTC)
    headers = incoming.headers
    body = await _read_body(
        incoming.receive, headers.get("content-length"), settings.max_body_bytes, settings.rejected_body_max_bytes
    )
    try:
        if type(body) is _Overflow:
            raise PayloadTooLarge(body.description(settings.max_body_bytes))
        _check_content_type(headers.get("content-type"))
        # A read: a 'values' layout comes from the store (memory; on
        # PostgreSQL a miss looks in the database, off the loop).
        parse = partial(
            parse_notification,
            body,
            headers,
            received_at=received_at,
            values_layout=store.values_layout,
            time_paths=parse_time_paths(settings.time_index_paths),
        )
        entities = await store.read(parse, memory_first=len(body) <= _PARSE_INLINE_MAX, consistent=False)
        # A write the database refuses for its content, every time, is
        # NotStorable (422): kept below like a refused notification, never a
        # 503 (Orion does not retry; a retry could not succeed anyway).
        await store.write(AppendSamples(entities))
    except TsdbError as exc:
        if exc.status < 500:
            await _keep_rejected(incoming, store, received_at, exc, body, settings.rejected_body_max_bytes)
        raise


# --- Content-Type ------------------------------------------------------------------
#
# Only JSON media types are notifications. This is a security boundary, not
# pedantry: a web page may make a visitor's browser POST cross-site without a
# CORS preflight only with text/plain, application/x-www-form-urlencoded,
# multipart/form-data or no Content-Type at all (a "simple" request). This
# endpoint has no authentication, so accepting any of those would let any web
# page write history into a deployment its visitors can reach. A JSON type
# forces the preflight, which we never grant.

_JSON_MEDIA = ("application/json", "application/ld+json", "application/geo+json")
_MEDIA_OK: dict[str, bool] = {}  # header value as received → accepted (a broker repeats the same one)


def _check_content_type(raw: str | None) -> None:
    if raw is None:
        raise UnsupportedMediaType(_media_advice(raw))
    ok = _MEDIA_OK.get(raw)
    if ok is None:
        media = raw.split(";", 1)[0].strip().lower()
        ok = media in _JSON_MEDIA or (media.startswith("application/") and media.endswith("+json"))
        if len(_MEDIA_OK) < 64:
            _MEDIA_OK[raw] = ok
    if not ok:
        raise UnsupportedMediaType(_media_advice(raw))


def _media_advice(raw: str | None) -> str:
    """What is wrong and how to fix the subscription that sent it."""
    got = "no Content-Type" if raw is None else f"Content-Type {raw[:80]!r}"
    return (
        f"notifications must be JSON (application/json, application/ld+json or application/geo+json), got {got}. "
        "An Orion custom notification (httpCustom) sends text/plain with 'payload' or with a Content-Type "
        "header override: use httpCustom 'json' instead of 'payload', or set httpCustom headers "
        '{"Content-Type": "application/json"}. The notification is kept: GET /v2/notify/rejected'
    )


# --- body ---------------------------------------------------------------------------


class _Overflow(bytes):
    """The first bytes of a body over the limit, and how big it really was."""

    size: int
    exact: bool

    def description(self, limit: int) -> str:
        size = f"{self.size} bytes" if self.exact else f"more than {self.size} bytes"
        return (
            f"notification of {size} exceeds the {limit}-byte limit (TSDB_MAX_BODY_BYTES); "
            "it is kept in GET /v2/notify/rejected"
        )


async def _read_body(receive, declared: str | None, limit: int, keep: int) -> bytes:
    """The body, or past ``limit`` an ``_Overflow`` with its first ``keep``
    bytes and its size, so an operator can still recover it."""
    chunks: list[bytes] = []
    size, more = 0, True
    while more:
        chunk, more = await _chunk(receive)
        if chunk:
            size += len(chunk)
            chunks.append(chunk)
            if size > limit:
                return await _overflow(_rest(receive, more), chunks, size, limit, keep, declared)
    return chunks[0] if len(chunks) == 1 and type(chunks[0]) is bytes else b"".join(chunks)


async def _chunk(receive) -> tuple[bytes, bool]:
    """The next piece of the body and whether more follows, read off the ASGI
    ``receive`` as Starlette's ``Request.stream`` reads it (a disconnect is
    ``ClientDisconnect``; other messages are skipped)."""
    while True:
        message = await receive()
        kind = message["type"]
        if kind == "http.request":
            return message.get("body", b""), message.get("more_body", False)
        if kind == "http.disconnect":
            raise ClientDisconnect()


async def _rest(receive, more: bool) -> AsyncIterator[bytes]:
    """The pieces after the one that went over the limit, then ``b""``, as
    ``Request.stream`` yields them."""
    while more:
        chunk, more = await _chunk(receive)
        if chunk:
            yield chunk
    yield b""


async def _overflow(stream, chunks: list[bytes], size: int, limit: int, keep: int, declared: str | None) -> _Overflow:
    known = int(declared) if declared is not None and declared.isdigit() else None
    head = bytearray(b"".join(chunks)[:keep])
    exact = True
    async for chunk in stream:
        size += len(chunk)
        if len(head) < keep:
            head += chunk[: keep - len(head)]
        elif known is not None:
            break  # the Content-Length says how big it is: no need to read the rest
        elif size > limit * _DRAIN_FACTOR:
            exact = False
            break
    body = _Overflow(head)
    body.size = known if known is not None else size
    body.exact = exact
    return body


# --- rejected store -----------------------------------------------------------------


async def _keep_rejected(
    incoming: _Incoming, store, received_at: datetime, exc: TsdbError, body: bytes, keep: int
) -> None:
    """Keep what the broker sent (headers, body, its size) before answering:
    Orion never sends a notification twice."""
    size = body.size if type(body) is _Overflow else len(body)
    kept = bytes(body[:keep])
    rejected = RejectedNotification(
        tenant=_rejected_tenant(incoming.request()),
        received_at=received_at,
        error=exc.error,
        description=exc.description,
        headers=orjson.dumps(redact_headers(incoming.headers, incoming.app.state.settings.api_key_header)).decode(),
        body=kept,
        body_size=size,
        body_truncated=len(kept) < size,
    )
    await store.write(RecordRejected(rejected))


def _rejected_tenant(request) -> str:
    """The tenant as the API names it; a header the API refuses is kept as
    received, for the operator's listing across tenants."""
    try:
        return tenant_of(request)
    except TsdbError:
        return tenant_header(request)


@router.get(
    "/v2/notify/rejected",
    summary="Notifications we answered with 4xx, newest first",
    **notify_oa.REJECTED,
)
@reads_store
def list_rejected(
    request: Request,
    limit: int = Query(100, ge=1, le=10_000),
    offset: int = Query(0, ge=0, le=MAX_INT_PARAM),
    all_tenants: bool = Query(
        False,
        alias="allTenants",
        description="Operator listing: every tenant's rejections, each with its tenant as stored (a tenant "
        "header the API refuses is stored as received). Ignores Fiware-Service. With authentication on, "
        "only a credential not restricted to tenants may ask (403 otherwise).",
    ),
) -> JSON:
    """Pages by count (``limit``) and by size (``TSDB_REJECTED_PAGE_MAX_BYTES``,
    at least one row): when more rows follow, ``Link: <...>; rel="next"``
    and ``X-Next-Offset`` say where the next page starts."""
    if all_tenants:
        require_every_tenant(request, "allTenants=true")
    tenant = None if all_tenants else tenant_of(request)
    max_bytes = request.app.state.settings.rejected_page_max_bytes
    rows, next_offset = store_of(request).rejected_page(tenant, limit, offset, max_bytes)
    response = JSON(rows)
    if next_offset is not None:
        url = request.url.include_query_params(offset=next_offset)
        response.headers["Link"] = f'<{url.path}?{url.query}>; rel="next"'
        response.headers["X-Next-Offset"] = str(next_offset)
    return response


@router.put(
    "/v2/notify/subscriptions/{subscription_id}",
    summary="Register the attribute list of a subscription that notifies in Orion's 'values' format",
    **notify_oa.PUT_LAYOUT,
)
async def put_layout(subscription_id: str, request: Request) -> JSON:
    tenant = tenant_of(request)
    try:
        doc = orjson.loads(await request.body())
    except orjson.JSONDecodeError as exc:
        raise ParseError(f"invalid JSON: {exc}") from None
    layout = layout_from_document(doc)
    await store_of(request).write(PutLayout(tenant, subscription_id, layout))
    return JSON(layout_document(layout), status_code=200)


@router.get(
    "/v2/notify/subscriptions",
    summary="Registered 'values' layouts of this tenant",
    **oa.spec(oa.FIWARE_SERVICE, oa.NGSILD_TENANT, ok_=oa.ok(notify_oa.LAYOUTS), errors_=(400, *oa.AUTH, 503)),
)
@reads_store
def list_layouts(request: Request) -> JSON:
    layouts = store_of(request).layouts(tenant_of(request))
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
    for name in attrs:
        if (problem := name_problem(name)) is not None:
            raise ParseError(f"attribute name {name[:80]!r} in 'attrs' {problem}: {RULE}")
    for name, value in (("entityId", entity_id), ("entityType", entity_type)):
        if value is not None and not isinstance(value, str):
            raise ParseError(f"'{name}' must be a string")
        if value and (problem := id_problem(value)) is not None:
            raise ParseError(f"'{name}' {value[:80]!r} {problem}: {ID_RULE}")
    if "id" not in attrs and not entity_id:
        raise ParseError("without an 'id' column in 'attrs', 'entityId' is required")
    return ValuesLayout(tuple(attrs), entity_id, entity_type)


def layout_document(layout: ValuesLayout) -> dict:
    return {"attrs": list(layout.attrs), "entityId": layout.entity_id, "entityType": layout.entity_type}
