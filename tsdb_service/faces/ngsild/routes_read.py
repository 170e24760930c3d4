"""The read half of the NGSI-LD temporal API (clauses 6.18.3.2, 6.19.3.1, 6.24):

* ``GET /ngsi-ld/v1/temporal/entities`` — query,
* ``GET /ngsi-ld/v1/temporal/entities/{entityId}`` — retrieve,
* ``POST /ngsi-ld/v1/temporal/entityOperations/query`` — query with a ``Query`` body.

Content negotiation: ``Accept: application/ld+json`` puts the @context in
the body; ``application/json`` (or none, or ``*/*``) names it in a ``Link``
header. The request's context comes from its ``Link`` header (or, for a
POST sent as ``application/ld+json``, the body's ``@context``).
"""

from __future__ import annotations

from collections.abc import Callable
from urllib.parse import urlencode

import orjson
from fastapi import APIRouter, Request
from starlette.responses import Response

from tsdb_service.core.errors import BadRequestData, InvalidRequest, NotAcceptable
from tsdb_service.core.timefmt import ld_iso as iso
from tsdb_service.faces.ngsild import openapi as ld_oa
from tsdb_service.faces.ngsild.context import JSONLD_CONTEXT_REL, ContextStore, TermMap, link_context
from tsdb_service.faces.ngsild.params import query_from_body, query_from_params
from tsdb_service.faces.ngsild.query import TemporalQuery
from tsdb_service.faces.ngsild.service import Cut, PageLink, TemporalResult, run
from tsdb_service.http.store import store_of
from tsdb_service.http.tenancy import caller_of, tenant_echo, tenant_of

router = APIRouter(prefix="/ngsi-ld/v1", tags=["NGSI-LD temporal"])
LD_JSON = "application/ld+json"
JSON = "application/json"


def contexts(request: Request) -> ContextStore:
    """The app's context store, made on first use from the settings."""
    state = request.app.state
    store = getattr(state, "ngsild_contexts", None)
    if store is None:
        store = state.ngsild_contexts = ContextStore.from_settings(state.settings)
    return store


def _limits(request: Request) -> tuple[int, int]:
    s = request.app.state.settings
    return s.ngsild_default_limit, s.ngsild_max_limit


def _cap(request: Request) -> int:
    return request.app.state.settings.ngsild_max_instances


def _tell(request: Request) -> bool:
    """Whether an unknown tenant is a NonexistentTenant: not with
    authentication on, where it would tell a caller which tenants exist."""
    return caller_of(request) is None


def accepted(header: str | None) -> str:
    """The response media type for an ``Accept`` header; 406 if none fits."""
    if not header or not header.strip():
        return JSON
    best, best_q = None, -1.0
    for part in header.split(","):
        fields = [f.strip() for f in part.split(";")]
        media = fields[0].lower()
        q = 1.0
        for f in fields[1:]:
            if f.startswith("q="):
                try:
                    q = float(f[2:])
                except ValueError:
                    q = 0.0
        if media in (LD_JSON, JSON, "*/*", "application/*") and q > best_q and q > 0:
            best, best_q = (LD_JSON if media == LD_JSON else JSON), q
            if media == LD_JSON:
                best_q += 0.0001  # an exact ld+json beats a wildcard at the same q
    if best is None:
        raise NotAcceptable(f"cannot answer with {header[:80]!r}: use application/json or application/ld+json")
    return best


@router.get("/temporal/entities", summary="Query temporal entities", **ld_oa.ld_read_spec())
async def query_entities(request: Request) -> Response:
    media = accepted(request.headers.get("accept"))
    params, limits = dict(request.query_params), _limits(request)
    return await _answer(
        request,
        media,
        link_context(request.headers.get("link")),
        lambda terms: query_from_params(params, tenant_of(request), terms, limits=limits),
        many=True,
    )


@router.get("/temporal/entities/{entity_id}", summary="Retrieve one temporal entity", **ld_oa.ld_read_spec())
async def retrieve_entity(entity_id: str, request: Request) -> Response:
    media = accepted(request.headers.get("accept"))
    if not entity_id or len(entity_id) > 2048:
        raise BadRequestData("the entity id must be 1 to 2048 characters")
    params = dict(request.query_params)
    return await _answer(
        request,
        media,
        link_context(request.headers.get("link")),
        lambda terms: query_from_params(params, tenant_of(request), terms, limits=(1, 1), entity_id=entity_id),
        many=False,
    )


@router.post(
    "/temporal/entityOperations/query",
    summary="Query temporal entities with a Query body",
    **ld_oa.ld_read_spec(body=ld_oa.LD_FRAGMENT_BODY),
)
async def query_post(request: Request) -> Response:
    media = accepted(request.headers.get("accept"))
    content_type = (request.headers.get("content-type") or "").split(";")[0].strip().lower()
    if content_type not in (JSON, LD_JSON):
        raise InvalidRequest("the body must be application/json or application/ld+json", status=415)
    raw = await request.body()  # at most TSDB_MAX_REQUEST_BODY_BYTES (http.bodies)
    try:
        body = orjson.loads(raw)
    except orjson.JSONDecodeError as exc:
        raise InvalidRequest(f"the body is not JSON: {exc}") from None
    link = request.headers.get("link")
    if content_type == LD_JSON:
        if link_context(link) is not None:
            raise BadRequestData("an application/ld+json body carries its @context; do not send a Link header too")
        if not isinstance(body, dict) or "@context" not in body:
            raise BadRequestData("an application/ld+json body needs an @context")
        context = body["@context"]
    else:
        if isinstance(body, dict) and "@context" in body:
            raise BadRequestData("an application/json body cannot carry @context: send application/ld+json")
        context = link_context(link)
    params, limits = dict(request.query_params), _limits(request)
    return await _answer(
        request,
        media,
        context,
        lambda terms: query_from_body(body, params, tenant_of(request), terms, limits=limits),
        many=True,
    )


async def _answer(
    request: Request,
    media: str,
    context: str | list | dict | None,
    parse: Callable[[TermMap], TemporalQuery],
    many: bool,
) -> Response:
    """Load ``context`` (on the event loop, within its deadline), then
    expand the terms with it, parse the query and run it off the loop, and
    answer in the media type asked for."""
    prepared = await contexts(request).prepare(context)

    def work() -> tuple[TemporalResult, TermMap, TemporalQuery]:
        terms = prepared.terms()
        query = parse(terms)
        querier = store_of(request).querier()
        return run(querier, terms, query, _cap(request), tell_tenants=_tell(request)), terms, query

    result, terms, query = await store_of(request).read(work, memory_first=False)
    return _respond(request, media, terms, result, query, many)


def _respond(request: Request, media: str, terms: TermMap, result: TemporalResult, query, many: bool) -> Response:
    headers: dict[str, str] = tenant_echo(request)
    links: list[str] = []
    if media == LD_JSON:
        for item in result.entities:
            item["@context"] = terms.response_context
    else:
        links.append(f'<{terms.link_url}>; rel="{JSONLD_CONTEXT_REL}"; type="{LD_JSON}"')
    if many:
        if query.count:
            headers["NGSILD-Results-Count"] = str(result.count)
        links += _page_links(request, query, result.count)
    status = 200
    if result.cut is not None:
        status = 206
        headers["Content-Range"] = result.cut.content_range
        if result.cut.window is not None and request.method == "GET":
            links.append(_continuation(request, result.cut))
    links += [_interval(request, page, media) for page in result.pages]
    if links:
        headers["Link"] = ", ".join(links)
    body = result.entities if many else result.entities[0]
    content = orjson.dumps(body, option=orjson.OPT_NON_STR_KEYS)
    return Response(content, status_code=status, media_type=media, headers=headers)


def _continuation(request: Request, cut: Cut) -> str:
    """The rest of a cut answer, as the newer drafts (ETSI TS 104 176) link
    it: the same request over the window the cut left (``Cut.window``)."""
    assert cut.window is not None
    timerel, at, end = cut.window
    params = [(k, v) for k, v in request.query_params.multi_items() if k not in ("timerel", "timeAt", "endTimeAt")]
    params += [("timerel", timerel), ("timeAt", iso(at))] + ([("endTimeAt", iso(end))] if end is not None else [])
    return f'<{request.url.path}?{urlencode(params)}>; rel="{cut.rel}"'


def _interval(request: Request, page: PageLink, media: str) -> str:
    """A page of TS 104 176's temporal pagination (clause 6.4.7.3): the same
    request with the page's ``offsetN`` and ``storedThrough`` (a POST's
    body is sent again to the link, whose query string carries them)."""
    changed = {name for name, _ in page.params}
    params = [(k, v) for k, v in request.query_params.multi_items() if k not in changed]
    return f'<{request.url.path}?{urlencode([*params, *page.params])}>; rel="{page.rel}"; type="{media}"'


def _page_links(request: Request, query, total: int) -> list[str]:
    """``Link`` rel next/prev for ``limit``/``offset`` paging (GET only: a
    POST's body cannot travel in a link, so there the links name only the
    changed query string)."""
    out: list[str] = []
    limit, offset = query.limit, query.offset
    if limit == 0:
        return out
    params = [(k, v) for k, v in request.query_params.multi_items() if k not in ("offset", "limit")]
    path = request.url.path
    if offset + limit < total:
        out.append(f'<{path}?{urlencode([*params, ("limit", limit), ("offset", offset + limit)])}>; rel="next"')
    if offset > 0:
        prev = max(0, offset - limit)
        out.append(f'<{path}?{urlencode([*params, ("limit", limit), ("offset", prev)])}>; rel="prev"')
    return out
