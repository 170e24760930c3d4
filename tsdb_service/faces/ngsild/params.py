"""HTTP → ``TemporalQuery``: the query string of ``GET /temporal/entities``
and ``GET /temporal/entities/{id}``, or a ``Query`` body of ``POST
/temporal/entityOperations/query``. Every name is expanded with the
request's @context (a ``TermMap``); every bad value is a BadRequestData.
The pieces every API shares (tenant, ``idPattern``, integer ranges, date-time
parsing, ``MAX_IDS``) come from ``parse.request_context``; what is NGSI-LD's
own (type expressions, ``timerel``, ``aggrMethods``, ISO 8601 durations,
paging with ``count``) is here.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import replace
from decimal import Decimal, InvalidOperation
from typing import Any
from urllib.parse import unquote

from tsdb_service.core.errors import BadRequest, BadRequestData, InvalidRequest, TooManyResults
from tsdb_service.faces.ngsild import boolexpr, qlang, scope
from tsdb_service.faces.ngsild.context import TermMap
from tsdb_service.faces.ngsild.geoquery import parse_ld_geo
from tsdb_service.faces.ngsild.query import (
    AGGR_METHODS,
    Aggregation,
    Duration,
    Format,
    GeoQuery,
    Selector,
    TemporalQuery,
    TimeProperty,
    TypeExpr,
    TypeName,
    Window,
)
from tsdb_service.parse.names import name_problem
from tsdb_service.parse.request_context import MAX_IDS, id_pattern, int_param, parse_time

MAX_LIST = 1000
MAX_ID_LENGTH = 2048
_URI = re.compile(r"[A-Za-z][A-Za-z0-9+.-]*:\S+\Z")
_DURATION = re.compile(
    r"^P(?:(\d+)Y)?(?:(\d+)M)?(?:(\d+)W)?(?:(\d+)D)?(?:T(?:(\d+)H)?(?:(\d+)M)?(?:(\d+(?:[.,]\d+)?)S)?)?$"
)
OPTIONS = ("temporalValues", "aggregatedValues", "sysAttrs", "keyValues", "normalized", "concise", "count")


def query_from_params(
    params: Mapping[str, str], tenant: str, terms: TermMap, *, limits: tuple[int, int], entity_id: str | None = None
) -> TemporalQuery:
    """``limits``: (default page size, maximum page size)."""
    get = params.get
    selectors = (Selector(),)
    if entity_id is None:
        selectors = (
            Selector(
                ids=_list(get("id"), "id", MAX_IDS),
                id_pattern=_ld(id_pattern, get("idPattern")),
                types=parse_types(get("type"), terms),
            ),
        )
    query = TemporalQuery(
        tenant=tenant,
        window=window(get("timerel"), get("timeAt"), get("endTimeAt"), get("timeproperty")),
        entity_id=entity_id,
        selectors=selectors,
        attrs=_names(get("attrs"), "attrs", terms),
        pick=_projection(get("pick"), "pick", terms),
        omit=_projection(get("omit"), "omit", terms),
        q=parse_q(get("q"), terms),
        scope_q=_scope_q(get("scopeQ")),
        geo=geo_query(get("georel"), get("geometry"), get("coordinates"), get("geoproperty"), terms),
        dataset_ids=_list(get("datasetId"), "datasetId"),
        last_n=_positive(get("lastN"), "lastN"),
        first_n=_positive(get("firstN"), "firstN"),
        offset_n=_non_negative(get("offsetN"), "offsetN"),
        stored_through=_positive(get("storedThrough"), "storedThrough"),
        as_of=_as_of(get("asOf")),
        local=_flag(get("local"), "local"),
        lang=languages(get("lang")),
    )
    check_instances(query)
    check_projection(query)
    query = _representation(
        query, get("options"), get("format"), get("aggrMethods"), get("aggrPeriodDuration"), InvalidRequest
    )
    check_as_of(query, timerel=get("timerel"))
    query = _paging(query, params, limits)
    check_csf(get("csf"))
    if entity_id is None:
        require_filter(query)
    return query


def query_from_body(
    body: Any, params: Mapping[str, str], tenant: str, terms: TermMap, *, limits: tuple[int, int]
) -> TemporalQuery:
    """A ``Query`` (clause 5.2.23) with ``temporalQ``; representation,
    paging and ``lastN`` may also come from the query string."""
    if not isinstance(body, dict):
        raise BadRequestData("the body must be a JSON object of type Query")
    if body.get("type") != "Query":
        raise BadRequestData("the body's type must be 'Query'")
    known = {
        "type",
        "entities",
        "attrs",
        "q",
        "geoQ",
        "temporalQ",
        "scopeQ",
        "lang",
        "csf",
        "@context",
        "pick",
        "omit",
        "datasetId",
        "aggrMethods",
        "aggrPeriodDuration",
        "lastN",
        "local",
    }
    unknown = sorted(set(body) - known)
    if unknown:
        raise BadRequestData(f"unknown Query members: {', '.join(u[:40] for u in unknown[:5])}")
    temporal = body.get("temporalQ", {})
    if not isinstance(temporal, dict):
        raise BadRequestData("temporalQ must be an object")
    geo = body.get("geoQ", {})
    if not isinstance(geo, dict):
        raise BadRequestData("geoQ must be an object")
    query = TemporalQuery(
        tenant=tenant,
        window=window(
            temporal.get("timerel"), temporal.get("timeAt"), temporal.get("endTimeAt"), temporal.get("timeproperty")
        ),
        selectors=_selectors(body.get("entities"), terms),
        attrs=_names(_joined(body.get("attrs"), "attrs"), "attrs", terms),
        pick=_projection(_joined(body.get("pick"), "pick"), "pick", terms),
        omit=_projection(_joined(body.get("omit"), "omit"), "omit", terms),
        q=parse_q(_string(body.get("q"), "q"), terms),
        scope_q=_scope_q(_string(body.get("scopeQ"), "scopeQ")),
        geo=geo_query(geo.get("georel"), geo.get("geometry"), geo.get("coordinates"), geo.get("geoproperty"), terms),
        dataset_ids=_list(_joined(body.get("datasetId"), "datasetId"), "datasetId"),
        last_n=_positive(_text(temporal.get("lastN", body.get("lastN", params.get("lastN")))), "lastN"),
        first_n=_positive(_text(temporal.get("firstN", params.get("firstN"))), "firstN"),
        offset_n=_non_negative(_text(temporal.get("offsetN", params.get("offsetN"))), "offsetN"),
        stored_through=_positive(params.get("storedThrough"), "storedThrough"),
        as_of=_as_of(params.get("asOf")),
        local=_flag(_text(body.get("local", params.get("local"))), "local"),
        lang=languages(_string(body.get("lang"), "lang") or params.get("lang")),
    )
    check_instances(query)
    check_projection(query)
    check_csf(_string(body.get("csf"), "csf") or params.get("csf"))
    methods = (
        _joined(temporal.get("aggrMethods"), "aggrMethods")
        or _joined(body.get("aggrMethods"), "aggrMethods")
        or params.get("aggrMethods")
    )
    period = temporal.get("aggrPeriodDuration") or body.get("aggrPeriodDuration") or params.get("aggrPeriodDuration")
    options, fmt = params.get("options"), params.get("format")
    if methods not in (None, "") and options in (None, "") and fmt in (None, ""):
        fmt = Format.AGGREGATED.value  # a TemporalQuery's aggrMethods ask for aggregation (clause 5.2.21)
    query = _representation(query, options, fmt, methods, period, BadRequestData)
    check_as_of(query, timerel=temporal.get("timerel"))
    query = _paging(query, params, limits)
    require_filter(query)
    return query


def check_instances(query: TemporalQuery) -> None:
    """``firstN`` (oldest first) and ``lastN`` (newest first) exclude each
    other (TS 104 176 clause 6.4.7.3: a page runs one way)."""
    if query.last_n is not None and query.first_n is not None:
        raise BadRequestData("lastN and firstN exclude each other: firstN pages oldest first, lastN newest first")


def check_as_of(query: TemporalQuery, timerel) -> None:
    """``asOf`` (our extension: the state at an instant) is its own window
    and its own instances: not with ``timerel``, ``lastN``, ``firstN``,
    ``offsetN`` or aggregation."""
    if query.as_of is None:
        return
    clashing = [
        name
        for name, given in (
            ("timerel", timerel not in (None, "")),
            ("lastN", query.last_n is not None),
            ("firstN", query.first_n is not None),
            ("offsetN", query.offset_n is not None or query.stored_through is not None),
            ("aggregatedValues", query.format is Format.AGGREGATED),
        )
        if given
    ]
    if clashing:
        raise BadRequestData(
            f"asOf (the state at an instant: each attribute's latest instance at or before it) cannot be combined "
            f"with {', '.join(clashing)}"
        )


def check_csf(raw: str | None) -> None:
    """``csf`` (clause 4.9's grammar over registration members): checked,
    and a query that is not one is a 400; one that is selects among
    context source registrations, of which this service has none, so the
    answer is the local history, as with ``local=true``."""
    if raw in (None, ""):
        return
    try:
        qlang.parse(str(raw))
    except qlang.QueryError as exc:
        raise BadRequestData(f"invalid csf: {exc}") from None


def check_projection(query: TemporalQuery) -> None:
    """Clause 4.21: ``pick`` and ``omit`` name no member in common, and
    neither goes with ``attrs`` (which they replace)."""
    if query.attrs is not None and (query.pick is not None or query.omit is not None):
        raise BadRequestData("attrs cannot be combined with pick or omit: pick and omit replace it")
    if query.pick is not None and query.omit is not None:
        both = [m for m in query.pick if m in query.omit]
        if both:
            raise BadRequestData(f"pick and omit both name {both[0][:80]!r}")


def require_filter(query: TemporalQuery) -> None:
    """Clause 5.7.3: a query names types, attributes, q, a geo-query or local
    scope; otherwise it would return the whole database."""
    has_type = any(s.types is not None for s in query.selectors)
    if not (has_type or query.attrs is not None or query.q is not None or query.geo is not None or query.local):
        raise BadRequestData("a temporal query needs at least one of type, attrs, q, a geo-query or local=true")


# --- ids and names in a URL path -------------------------------------------------


def uri(value: Any, what: str) -> str:
    """An entity id or instanceId: a URI (clause 4.5.1), else BadRequestData."""
    if type(value) is not str or len(value) > MAX_ID_LENGTH or not _URI.match(value):
        raise BadRequestData(f"{what} must be a URI, not {str(value)[:200]!r}")
    return value


def attribute_name(value: str) -> str:
    """An attribute name from a URL path segment, else BadRequestData
    (clause 5.6.13.4): one the ingest could have stored (``parse.names``),
    and no dot segment even once its percent triplets are decoded (a
    relative reference would resolve it to another resource)."""
    problem = name_problem(value)
    if problem is None and unquote(value).strip() in (".", ".."):
        problem = "is a dot segment"
    if problem is not None:
        raise BadRequestData(f"attribute name {value[:200]!r} {problem}")
    return value


# --- the temporal query -----------------------------------------------------------


def window(timerel, time_at, end_time_at, timeproperty) -> Window:
    prop = TimeProperty.OBSERVED_AT
    if timeproperty not in (None, ""):
        try:
            prop = TimeProperty(str(timeproperty))
        except ValueError:
            raise BadRequestData(
                f"timeproperty must be one of {', '.join(p.value for p in TimeProperty)}, "
                f"not {str(timeproperty)[:40]!r}"
            ) from None
    if timerel in (None, ""):
        if time_at not in (None, "") or end_time_at not in (None, ""):
            raise BadRequestData("timeAt and endTimeAt need timerel")
        return Window(timeproperty=prop)
    if timerel not in ("before", "after", "between"):
        raise BadRequestData(f"timerel must be before, after or between, not {str(timerel)[:40]!r}")
    if time_at in (None, ""):
        raise BadRequestData(f"timerel={timerel} needs timeAt")
    at = _time(time_at, "timeAt")
    if timerel == "before":
        return Window("before", None, at, prop)
    if timerel == "after":
        return Window("after", at, None, prop)
    if end_time_at in (None, ""):
        raise BadRequestData("timerel=between needs endTimeAt")
    end = _time(end_time_at, "endTimeAt")
    if end <= at:
        raise BadRequestData("endTimeAt must be later than timeAt")
    return Window("between", at, end, prop)


def _as_of(raw: str | None):
    """``asOf``: a DateTime (clause 4.6.3), or None."""
    return None if raw in (None, "") else _time(raw, "asOf")


def _time(raw: Any, name: str):
    if not isinstance(raw, str):
        raise BadRequestData(f"{name} must be a date-time string")
    text = raw.strip().strip('"')
    if len(text) < 11 or text[10] not in "Tt":
        raise BadRequestData(f"{name} must be a DateTime (clause 4.6.3) such as 2024-05-01T10:00:00Z, not {raw[:80]!r}")
    try:
        return parse_time(raw, name)
    except BadRequest as exc:
        raise BadRequestData(exc.description) from None


# --- entities ---------------------------------------------------------------------


def parse_types(raw: str | None, terms: TermMap) -> TypeExpr | None:
    """A type expression (clause 4.17): ``,`` and ``|`` are OR, ``;`` is
    AND, parentheses group; ``;`` binds tighter."""
    if raw in (None, ""):
        return None
    found = boolexpr.tokens(raw, ",|", "type expression")
    names = [t for t in found if t not in "(),;|"]
    if len(names) > MAX_LIST:
        raise BadRequestData(f"type lists more than {MAX_LIST} types")
    expanded = dict(zip(names, terms.expand_all(names), strict=True))
    return boolexpr.parse(raw, found, ",|", "type expression", lambda name: TypeName(expanded[name], name))


def _selectors(raw: Any, terms: TermMap) -> tuple[Selector, ...]:
    if raw is None:
        return (Selector(),)
    if not isinstance(raw, list) or not raw or len(raw) > MAX_LIST:
        raise BadRequestData("entities must be a non-empty array of EntitySelectors")
    out = []
    for item in raw:
        if not isinstance(item, dict) or not set(item) <= {"id", "idPattern", "type"}:
            raise BadRequestData("each EntitySelector has only id, idPattern and type")
        ident = item.get("id")
        if ident is not None and (not isinstance(ident, str) or not ident or len(ident) > MAX_ID_LENGTH):
            raise BadRequestData("an EntitySelector id must be a non-empty string")
        out.append(
            Selector(
                ids=(ident,) if ident else None,
                id_pattern=_ld(id_pattern, _string(item.get("idPattern"), "idPattern")),
                types=parse_types(_string(item.get("type"), "type"), terms),
            )
        )
    return tuple(out)


# --- attributes, q, geo -------------------------------------------------------------


# Members the system keeps for every attribute or entity (clauses 4.8, 5.2.2):
# no attribute of an entity is named so.
SYSTEM_MEMBERS = frozenset({"createdAt", "modifiedAt", "deletedAt", "observedAt", "id", "type", "@id", "@type"})
_CORE = "https://uri.etsi.org/ngsi-ld/"


def _names(raw: str | None, name: str, terms: TermMap) -> tuple[str, ...] | None:
    """``attrs``: attribute names, expanded; one naming only system members
    (``attrs=createdAt``) asks for no attribute at all: BadRequestData."""
    items = _list(raw, name)
    if items is None:
        return None
    _no_linked_entities(items, name)
    iris = terms.expand_all(items)
    system = {_CORE + member for member in SYSTEM_MEMBERS} | SYSTEM_MEMBERS
    if all(item in SYSTEM_MEMBERS or iri in system for item, iri in zip(items, iris, strict=True)):
        raise BadRequestData(
            f"{name} names only system members ({', '.join(i[:40] for i in items[:5])}): they are no attributes; "
            "ask for sysAttrs in options to see createdAt and modifiedAt"
        )
    return tuple(dict.fromkeys(iris))


def _no_linked_entities(items: tuple[str, ...], name: str) -> None:
    """Linked-entity projection (``owner{name}``, V1.9.1's linked-entity
    retrieval) is not part of the temporal API: BadRequestData, not a name
    no attribute has."""
    braced = next((item for item in items if "{" in item or "}" in item), None)
    if braced is not None:
        raise BadRequestData(
            f"{name} {braced[:80]!r}: linked-entity projection ({{...}}) is not supported by the temporal API"
        )


def _projection(raw: str | None, name: str, terms: TermMap) -> tuple[str, ...] | None:
    """pick/omit: ``id``, ``type`` and attribute names."""
    items = _list(raw, name)
    if items is None:
        return None
    _no_linked_entities(items, name)
    attrs = [i for i in items if i not in ("id", "type")]
    expanded = dict(zip(attrs, terms.expand_all(attrs), strict=True))
    return tuple(dict.fromkeys(i if i in ("id", "type") else expanded[i] for i in items))


def parse_q(raw: str | None, terms: TermMap) -> qlang.Node | None:
    if raw in (None, ""):
        return None
    try:
        node = qlang.parse(raw)
    except qlang.QueryError as exc:
        raise BadRequestData(f"invalid q: {exc}") from None
    names = sorted({t.attr for t in qlang.terms(node)})
    expanded = dict(zip(names, terms.expand_all(names), strict=True))
    return qlang.map_attrs(node, expanded.__getitem__)


def _scope_q(raw: str | None) -> scope.ScopeExpr | None:
    return None if raw in (None, "") else scope.parse(str(raw))


def geo_query(georel, geometry, coordinates, geoproperty, terms: TermMap) -> GeoQuery | None:
    geo = parse_ld_geo(georel, geometry, coordinates)
    if geo is None:
        if geoproperty not in (None, ""):
            raise BadRequestData("geoproperty needs georel, geometry and coordinates")
        return None
    prop = terms.expand(str(geoproperty)) if geoproperty not in (None, "") else terms.expand("location")
    return GeoQuery(geo, prop)


# --- representation, paging --------------------------------------------------------

_LANGUAGE_RANGE = re.compile(r"(?:\*|[A-Za-z]{1,8}(?:-[A-Za-z0-9]{1,8})*)\Z")
_QUALITY = re.compile(r"q=(?:0(?:\.\d{0,3})?|1(?:\.0{0,3})?)\Z")


def languages(raw: str | None) -> tuple[tuple[str, float], ...] | None:
    """``lang`` (clause 4.15): language ranges (RFC 4647, as in
    Accept-Language: ``fr``, ``en-GB;q=0.8``, ``*``), best first."""
    if raw in (None, ""):
        return None
    ranges = []
    for i, item in enumerate(str(raw).split(",")):
        tag, _, quality = (part.strip() for part in item.partition(";"))
        if not _LANGUAGE_RANGE.match(tag) or (quality and not _QUALITY.match(quality)):
            raise BadRequestData(f"lang must list language tags such as fr or en-GB;q=0.8, not {str(raw)[:80]!r}")
        q = float(quality[2:]) if quality else 1.0
        if q > 0:
            ranges.append((tag.lower(), q, i))
    ranges.sort(key=lambda r: (-r[1], r[2]))
    return tuple((tag, q) for tag, q, _ in ranges)


def _representation(query: TemporalQuery, options, fmt, methods, period, invalid: type[BadRequest]) -> TemporalQuery:
    """``format`` wins over ``options``; ``temporalValues,aggregatedValues``
    together mean aggregation (a common Grafana plugin sends both). An
    unknown ``format`` or option is an InvalidRequest (a parameter value
    outside its grammar); ``aggrMethods`` and ``aggrPeriodDuration`` are
    checked, and used only when aggregating: an unknown method or a
    duration that is none is ``invalid``'s error (InvalidRequest in a query
    string, as ``format`` and ``options``; BadRequestData in a ``Query``
    body, a TemporalQuery member that does not meet clause 5.2.21)."""
    opts = _list(options, "options") or ()
    unknown = [o for o in opts if o not in OPTIONS]
    if unknown:
        raise InvalidRequest(f"unknown options: {', '.join(o[:40] for o in unknown)}; use {', '.join(OPTIONS)}")
    chosen = Format.NORMALIZED
    if fmt not in (None, ""):
        try:
            chosen = Format(fmt)
        except ValueError:
            raise InvalidRequest(
                f"format must be normalized, concise, temporalValues or aggregatedValues, not {str(fmt)[:40]!r}"
            ) from None
    elif "aggregatedValues" in opts:
        chosen = Format.AGGREGATED
    elif "temporalValues" in opts:
        chosen = Format.TEMPORAL_VALUES
    elif "concise" in opts:
        chosen = Format.CONCISE
    aggregation = None
    if chosen is Format.AGGREGATED:
        aggregation = Aggregation(_methods(methods, invalid), parse_duration(period, invalid))
    else:
        if methods not in (None, ""):
            _methods(methods, invalid)
        parse_duration(period, invalid)
    return replace(
        query,
        format=chosen,
        aggregation=aggregation,
        sys_attrs="sysAttrs" in opts,
        count=query.count or "count" in opts,
    )


def _methods(raw, invalid: type[BadRequest] = BadRequestData) -> tuple[str, ...]:
    items = _list(raw, "aggrMethods")
    if not items:
        raise BadRequestData("aggregatedValues needs aggrMethods")
    bad = [m for m in items if m not in AGGR_METHODS]
    if bad:
        raise invalid(f"unknown aggrMethods {', '.join(b[:40] for b in bad)}: use {', '.join(AGGR_METHODS)}")
    return tuple(dict.fromkeys(items))


def parse_duration(raw, invalid: type[BadRequest] = BadRequestData) -> Duration:
    """ISO 8601 ``PnYnMnWnDTnHnMnS`` (weeks may mix with the rest, as many
    parsers allow); absent means ``PT0S``, the whole window."""
    if raw in (None, ""):
        return Duration()
    text = str(raw).strip()
    match = _DURATION.match(text)
    if not match or text in ("P", "PT") or text.endswith("T"):
        raise invalid(f"aggrPeriodDuration must be an ISO 8601 duration such as PT1H or P1M, not {text[:40]!r}")
    y, mo, w, d, h, mi, s = match.groups()
    try:
        seconds = Decimal((s or "0").replace(",", "."))
    except InvalidOperation:
        raise invalid(f"bad seconds in aggrPeriodDuration {text[:40]!r}") from None
    months = int(y or 0) * 12 + int(mo or 0)
    days = int(w or 0) * 7 + int(d or 0)
    micros = (int(h or 0) * 3600 + int(mi or 0) * 60) * 1_000_000 + int(seconds * 1_000_000)
    if months > 12 * 10_000 or days > 3_660_000 or micros > 10**17:
        raise BadRequestData(f"aggrPeriodDuration {text[:40]!r} is too long")
    return Duration(months, days, micros)


def _paging(query: TemporalQuery, params: Mapping[str, str], limits: tuple[int, int]) -> TemporalQuery:
    default_limit, max_limit = limits
    limit = _non_negative(params.get("limit"), "limit")
    if limit is not None and limit > max_limit:
        raise TooManyResults(f"limit must be at most {max_limit}")
    offset = _non_negative(params.get("offset"), "offset") or 0
    count = _flag(params.get("count"), "count") or query.count
    descending = _order(params.get("orderBy"))
    if limit == 0 and not count:
        raise BadRequestData("limit=0 needs count=true")
    limit = default_limit if limit is None else limit
    return replace(query, limit=limit, offset=offset, count=count, descending=descending)


def _order(raw: str | None) -> bool:
    """``orderBy`` (clause 4.23): the temporal query orders by ``id`` only
    (clause 5.7.4.4: any other member is a BadRequestData), ascending or,
    with ``id;desc``, descending. True: descending."""
    if raw in (None, ""):
        return False
    items = [item.strip() for item in str(raw).split(",")]
    directions = set()
    for item in items:
        member, _, direction = item.partition(";")
        if member.strip() != "id" or direction.strip() not in ("", "asc", "desc"):
            raise BadRequestData(f"orderBy orders temporal entities by id only (id, id;asc, id;desc), not {raw[:80]!r}")
        directions.add(direction.strip() == "desc")
    if len(directions) > 1:
        raise BadRequestData(f"orderBy names id twice in two directions: {raw[:80]!r}")
    return directions.pop()


# --- small parsers ------------------------------------------------------------------


def _list(raw: str | None, name: str, most: int = MAX_LIST) -> tuple[str, ...] | None:
    if raw is None:
        return None
    items = tuple(dict.fromkeys(part.strip() for part in str(raw).split(",") if part.strip()))
    if not items:
        raise BadRequestData(f"{name} is empty")
    if len(items) > most:
        raise BadRequestData(f"{name} lists more than {most} items")
    if any(len(i) > MAX_ID_LENGTH for i in items):
        raise BadRequestData(f"{name} has an item longer than {MAX_ID_LENGTH} characters")
    return items


def _joined(raw: Any, name: str) -> str | None:
    """Body members may be a list of strings or one comma-separated string."""
    if raw is None:
        return None
    if isinstance(raw, list) and all(isinstance(i, str) for i in raw):
        return ",".join(raw) if raw else None
    if isinstance(raw, str):
        return raw
    raise BadRequestData(f"{name} must be a string or an array of strings")


def _string(raw: Any, name: str) -> str | None:
    if raw is None or isinstance(raw, str):
        return raw
    raise BadRequestData(f"{name} must be a string")


def _text(raw: Any) -> str | None:
    if raw is None or isinstance(raw, str):
        return raw
    if isinstance(raw, bool):
        return "true" if raw else "false"
    return str(raw)


def _positive(raw: str | None, name: str) -> int | None:
    return _ld(int_param, raw, name, 1)


def _non_negative(raw: str | None, name: str) -> int | None:
    return _ld(int_param, raw, name, 0)


def _ld(parse, *args):
    """A shared parser's (``parse.request_context``) 400 as this API's
    BadRequestData: the same ProblemDetails, and the class NGSI-LD callers
    expect."""
    try:
        return parse(*args)
    except BadRequest as exc:
        raise BadRequestData(exc.description) from None


def _flag(raw: str | None, name: str) -> bool:
    if raw in (None, ""):
        return False
    if raw not in ("true", "false"):
        raise BadRequestData(f"{name} must be true or false, not {str(raw)[:40]!r}")
    return raw == "true"
