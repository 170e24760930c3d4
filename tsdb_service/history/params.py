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
from .query import (
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
from .valuepath import parse_attr_list, parse_value_path

_INT = re.compile(r"\+?\d{1,18}\Z")
_MAX_PATTERN = 512
_MAX_IDS = 10_000
_MAX_SERVICE_PATHS = 50
_SP_COMPONENT = re.compile(r"[^/#\s]{1,256}\Z")

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
    """One of the six history endpoints; path segments come as keywords."""
    get = params.get
    scope = Scope(tenant, service_paths(headers.get("fiware-servicepath")))
    if entity_id is not None:
        _check_entity_id(entity_id, "entityId")
        entities = EntityFilter(ids=(entity_id,), types=_types(get("type")))
    elif entity_type is not None:
        _check_name(entity_type, "entityType")
        entities = EntityFilter(ids=_ids(get("id")), id_pattern=_pattern(get("idPattern")), types=(entity_type,))
    else:
        entities = EntityFilter(ids=_ids(get("id")), id_pattern=_pattern(get("idPattern")), types=_types(get("type")))

    if attr is not None:
        attrs: tuple[ValuePath, ...] | None = (parse_value_path(attr),)
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
        _check_entity_id(entity_id, "entityId")
        entities = EntityFilter(ids=(entity_id,), types=_types(get("type")))
    else:
        _check_name(entity_type or "", "entityType")
        entities = EntityFilter(types=(entity_type,))
    drop = get("dropTable")
    if drop is not None and drop.lower() not in ("true", "false"):
        raise BadRequest(f"dropTable must be true or false, not {drop[:40]!r}")
    return DeleteQuery(scope, entities, time_range(get("fromDate"), get("toDate")))


# --- pieces, shared with the other routes -----------------------------------------


def service_paths(header: str | None) -> tuple[str, ...]:
    """``Fiware-ServicePath`` for a query: a comma list of paths, each
    optionally ending in ``/#``. Missing or ``/`` means the whole tenant."""
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
        if not path.startswith("/"):
            raise BadRequest(f"bad Fiware-ServicePath {part[:80]!r}: each path must start with '/'")
        if len(path) > 1:
            path = path.rstrip("/") if path != "/" else path
            components = path[1:].split("/")
            if not all(_SP_COMPONENT.match(c) for c in components):
                raise BadRequest(f"bad Fiware-ServicePath {part[:80]!r}")
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
        raise BadRequest(f"{name} must be an ISO 8601 date-time such as 2024-05-01T10:00:00Z, not {raw[:80]!r}") from None
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


def _positive(raw: str | None, name: str) -> int | None:
    if raw is None or raw == "":
        return None
    if not _INT.match(raw.strip()):
        raise BadRequest(f"{name} must be a positive integer, not {raw[:40]!r}")
    value = int(raw)
    if value < 1:
        raise BadRequest(f"{name} must be a positive integer, not {raw[:40]!r}")
    return value


def _non_negative(raw: str | None, name: str) -> int | None:
    if raw is None or raw == "":
        return None
    if not _INT.match(raw.strip()):
        raise BadRequest(f"{name} must be a non-negative integer, not {raw[:40]!r}")
    return int(raw)


def _ids(raw: str | None) -> tuple[str, ...] | None:
    if raw is None:
        return None
    ids = tuple(dict.fromkeys(part.strip() for part in raw.split(",") if part.strip()))
    if not ids:
        return None
    if len(ids) > _MAX_IDS:
        raise BadRequest(f"id lists at most {_MAX_IDS} entity ids")
    return ids


def _types(raw: str | None) -> tuple[str, ...] | None:
    if raw is None:
        return None
    types = tuple(dict.fromkeys(part.strip() for part in raw.split(",") if part.strip()))
    return types or None


def _pattern(raw: str | None) -> str | None:
    if raw is None or raw == "":
        return None
    if len(raw) > _MAX_PATTERN:
        raise BadRequest(f"idPattern is longer than {_MAX_PATTERN} characters")
    try:
        re.compile(raw)
    except re.error as exc:
        raise BadRequest(f"idPattern is not a valid regular expression: {exc}") from None
    return raw


def _no_options(raw: str | None) -> None:
    if raw not in (None, ""):
        raise BadRequest(f"options={raw[:40]!r} is not supported", error="NotSupported")


def _check_entity_id(value: str, name: str) -> None:
    if not value or len(value) > 1024:
        raise BadRequest(f"{name} must be 1 to 1024 characters")


def _check_name(value: str, name: str) -> None:
    if not value or len(value) > 1024:
        raise BadRequest(f"{name} must be 1 to 1024 characters")
