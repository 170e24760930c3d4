"""HTTP query parameters and headers → frozen history queries, or a 400.

Every parameter is checked here, once, so storage never sees a value it
cannot handle and no parameter combination can end in a 500. Parsing is
deliberately plain Python (no pydantic): it runs on every read request.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from datetime import UTC, datetime

from ..errors import BadRequest
from ..idpattern import compile_pattern
from ..ngsi.names import (
    ID_RULE,
    SERVICE_PATH_RULE,
    id_problem,
    normalize_service_path,
    service_path_problem,
)
from ..query import (
    Aggregation,
    AggrMethod,
    AggrPeriod,
    AggrScope,
    DeleteQuery,
    EntityFilter,
    EntityListQuery,
    HistoryQuery,
    Scope,
    Shape,
    TimeRange,
    ValuePath,
)
from ..rawpath import unescape_segment
from .valuepath import parse_attr_list, parse_value_path

_INT = re.compile(r"\+?[0-9]{1,20}\Z")
# The largest integer any parameter may take (limits, offsets, lastN,
# Grafana point counts): 2^53 - 1, exact in every JSON client.
MAX_INT_PARAM = 2**53 - 1
_MAX_IDS = 10_000
_MAX_SERVICE_PATHS = 50

_METHODS = {m.value: m for m in AggrMethod}
_PERIODS = {p.value: p for p in AggrPeriod}
_SCOPES = {s.value: s for s in AggrScope}
_GEO_PARAMS = ("georel", "geometry", "coords")


def history_query(
    shape: Shape,
    params: Mapping[str, str],
    headers: Mapping[str, str],
    tenant: str,
    default_limit: int,
    *,
    entity_id: str | None = None,
    entity_type: str | None = None,
    attr: str | None = None,
    values_only: bool = False,
) -> HistoryQuery:
    """One of the six history endpoints; path segments come as keywords,
    as routed (see ``tsdb_service.rawpath``)."""
    get = params.get
    scope = Scope(tenant, service_paths(headers.get("fiware-servicepath")))
    if entity_id is not None:
        entity_id = _segment(entity_id, "entityId")
        entities = EntityFilter(ids=(entity_id,), types=_types(get("type")))
    elif entity_type is not None:
        entity_type = _segment(entity_type, "entityType")
        entities = EntityFilter(ids=_ids(get("id")), id_pattern=_pattern(get("idPattern")), types=(entity_type,))
    else:
        entities = EntityFilter(ids=_ids(get("id")), id_pattern=_pattern(get("idPattern")), types=_types(get("type")))

    if attr is not None:
        attrs: tuple[ValuePath, ...] | None = (parse_value_path(unescape_segment(attr)),)
    else:
        attrs = parse_attr_list(get("attrs"))

    last_n = _positive(get("lastN"), "lastN")
    limit = _positive(get("limit"), "limit")
    limit = default_limit if limit is None else min(limit, default_limit)
    offset = _non_negative(get("offset"), "offset") or 0
    _no_options(get("options"))
    return HistoryQuery(
        shape=shape,
        scope=scope,
        entities=entities,
        attrs=attrs,
        time=time_range(get("fromDate"), get("toDate")),
        last_n=last_n,
        limit=limit,
        offset=offset,
        aggregation=aggregation(get("aggrMethod"), get("aggrPeriod"), get("aggrScope")),
        values_only=values_only,
        geo=geo_filter(params),
    )


def entity_list_query(
    params: Mapping[str, str], headers: Mapping[str, str], tenant: str, default_limit: int
) -> EntityListQuery:
    get = params.get
    limit = _positive(get("limit"), "limit")
    return EntityListQuery(
        scope=Scope(tenant, service_paths(headers.get("fiware-servicepath"))),
        entities=EntityFilter(ids=_ids(get("id")), id_pattern=_pattern(get("idPattern")), types=_types(get("type"))),
        time=time_range(get("fromDate"), get("toDate")),
        limit=default_limit if limit is None else min(limit, default_limit),
        offset=_non_negative(get("offset"), "offset") or 0,
        geo=geo_filter(params),
    )


def delete_query(
    params: Mapping[str, str],
    headers: Mapping[str, str],
    tenant: str,
    *,
    entity_id: str | None = None,
    entity_type: str | None = None,
) -> DeleteQuery:
    get = params.get
    scope = Scope(tenant, service_paths(headers.get("fiware-servicepath")))
    if entity_id is not None:
        entity_id = _segment(entity_id, "entityId")
        entities = EntityFilter(ids=(entity_id,), types=_types(get("type")))
    else:
        entity_type = _segment(entity_type or "", "entityType")
        entities = EntityFilter(types=(entity_type,))
    drop = get("dropTable")
    if drop is not None and drop.lower() not in ("true", "false"):
        raise BadRequest(f"dropTable must be true or false, not {drop[:40]!r}")
    return DeleteQuery(scope, entities, time_range(get("fromDate"), get("toDate")))


# --- pieces, shared with the other routes -----------------------------------------


def service_paths(header: str | None) -> tuple[str, ...]:
    """``Fiware-ServicePath`` for a query: a comma list of paths, each
    optionally ending in ``/#``. Missing or ``/`` means the whole tenant.
    Each path follows the ingest's rule (``ngsi.names``)."""
    if header is None or not header.strip():
        return ("/",)
    parts = [part.strip() for part in header.split(",")]
    if len(parts) > _MAX_SERVICE_PATHS:
        raise BadRequest(f"Fiware-ServicePath lists more than {_MAX_SERVICE_PATHS} paths")
    out: list[str] = []
    for part in parts:
        path = part
        if path.endswith("/#"):
            path = path[:-2] or "/"
        elif path == "#":
            path = "/"
        path = normalize_service_path(path)
        problem = service_path_problem(path)
        if problem is not None:
            raise BadRequest(f"bad Fiware-ServicePath {part[:80]!r}: {problem} ({SERVICE_PATH_RULE})")
        if path not in out:
            out.append(path)
    return ("/",) if "/" in out else tuple(out)


def parse_time(raw: str, name: str) -> datetime:
    """ISO 8601 with any offset (naive means UTC), optionally quoted."""
    text = raw.strip().strip('"').strip()
    try:
        if len(text) > 64:
            raise ValueError("too long")
        moment = datetime.fromisoformat(text)
    except ValueError:
        raise BadRequest(
            f"{name} must be an ISO 8601 date-time such as 2024-05-01T10:00:00Z, not {raw[:80]!r}"
        ) from None
    if moment.tzinfo is None:
        return moment.replace(tzinfo=UTC)
    try:
        return moment.astimezone(UTC)
    except (OverflowError, ValueError):
        raise BadRequest(f"{name} {raw[:80]!r} is out of range") from None


def time_range(from_raw: str | None, to_raw: str | None) -> TimeRange:
    start = parse_time(from_raw, "fromDate") if from_raw not in (None, "") else None
    end = parse_time(to_raw, "toDate") if to_raw not in (None, "") else None
    return TimeRange(start, end)


def aggregation(method: str | None, period: str | None, scope: str | None) -> Aggregation | None:
    if method in (None, ""):
        if period not in (None, ""):
            raise BadRequest("aggrMethod is compulsory when using aggrPeriod.", error="Bad parameters use")
        if scope not in (None, "", "entity", "global"):
            raise BadRequest(f"aggrScope must be one of entity, global, not {scope[:40]!r}")
        return None
    m = _METHODS.get(method.lower())
    if m is None:
        raise BadRequest(f"aggrMethod must be one of {', '.join(_METHODS)}, not {method[:40]!r}")
    p = None
    if period not in (None, ""):
        p = _PERIODS.get(period.lower())
        if p is None:
            raise BadRequest(f"aggrPeriod must be one of {', '.join(_PERIODS)}, not {period[:40]!r}")
    s = AggrScope.ENTITY
    if scope not in (None, ""):
        s = _SCOPES.get(scope.lower())
        if s is None:
            raise BadRequest(f"aggrScope must be one of {', '.join(_SCOPES)}, not {scope[:40]!r}")
    return Aggregation(m, p, s)


def geo_filter(params: Mapping[str, str]) -> object | None:
    """``georel``, ``geometry`` and ``coords`` as a ``GeoFilter`` (or None);
    ``geoScope`` chooses sample (default) or entity semantics."""
    from ..geo.filter import parse_geo

    return parse_geo(params.get("georel"), params.get("geometry"), params.get("coords"), params.get("geoScope"))


def int_param(raw: str | None, name: str, low: int) -> int | None:
    """A decimal integer from ``low`` to ``MAX_INT_PARAM``, or None when absent.

    The one integer rule of every endpoint: the bound keeps any value far
    inside what both databases (64-bit) and JSON clients (53-bit) can hold,
    so no integer a client sends can fail anywhere past this check."""
    if raw is None or raw == "":
        return None
    text = raw.strip()
    kind = "a positive" if low == 1 else "a non-negative" if low == 0 else f"an integer from {low}, as"
    if not _INT.match(text) or int(text) < low:
        raise BadRequest(f"{name} must be {kind} integer, not {raw[:40]!r}")
    if int(text) > MAX_INT_PARAM:
        raise BadRequest(f"{name} must be {kind} integer up to {MAX_INT_PARAM}, not {raw[:40]!r}")
    return int(text)


def _positive(raw: str | None, name: str) -> int | None:
    return int_param(raw, name, 1)


def _non_negative(raw: str | None, name: str) -> int | None:
    return int_param(raw, name, 0)


def _ids(raw: str | None) -> tuple[str, ...] | None:
    ids = _id_list(raw, "id")
    if ids is not None and len(ids) > _MAX_IDS:
        raise BadRequest(f"id lists at most {_MAX_IDS} entity ids")
    return ids


def _types(raw: str | None) -> tuple[str, ...] | None:
    return _id_list(raw, "type")


def _id_list(raw: str | None, name: str) -> tuple[str, ...] | None:
    """A comma list of entity ids or types, each following the ingest's rule."""
    if raw is None:
        return None
    items = tuple(dict.fromkeys(part.strip() for part in raw.split(",") if part.strip()))
    for item in items:
        check_id(item, name)
    return items or None


def _pattern(raw: str | None) -> str | None:
    if raw is None or raw == "":
        return None
    compile_pattern(raw)  # RE2, linear time: see tsdb_service.idpattern
    return raw


def _no_options(raw: str | None) -> None:
    if raw not in (None, ""):
        raise BadRequest(f"options={raw[:40]!r} is not supported", error="NotSupported")


def _segment(raw: str, name: str) -> str:
    """An entity id or type from a URL path segment."""
    value = unescape_segment(raw)
    check_id(value, name)
    return value


def check_id(value: str, name: str) -> None:
    """An entity id or type as the ingest accepts them (``ngsi.names``)."""
    problem = id_problem(value)
    if problem is not None:
        raise BadRequest(f"{name} {value[:80]!r} {problem}: {ID_RULE}")
