"""HTTP query parameters and headers → frozen history queries, or a 400.

Every parameter is checked here, once, so storage never sees a value it
cannot handle and no parameter combination can end in a 500. The request
context (tenant, service paths, entity filter, limits, aggregation, time
range) is read by ``parse.request_context``, the parser every API shares;
this module assembles the history API's queries from it. Parsing is
deliberately plain Python (no pydantic): it runs on every read request.
"""

from __future__ import annotations

from collections.abc import Mapping

from tsdb_service.core.errors import BadRequest
from tsdb_service.core.query import DeleteQuery, EntityFilter, EntityListQuery, HistoryQuery, Shape, ValuePath
from tsdb_service.history.valuepath import parse_attr_list, parse_value_path
from tsdb_service.http.rawpath import unescape_segment
from tsdb_service.parse.request_context import (
    aggregation,
    check_id,
    entity_filter,
    id_list,
    id_pattern,
    non_negative,
    page_limit,
    positive,
    scope,
    time_range,
)


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
    as routed (see ``tsdb_service.http.rawpath``)."""
    get = params.get
    where = scope(headers, tenant)
    if entity_id is not None:
        entity_id = _segment(entity_id, "entityId")
        entities = EntityFilter(ids=(entity_id,), types=id_list(get("type"), "type"))
    elif entity_type is not None:
        entity_type = _segment(entity_type, "entityType")
        entities = EntityFilter(
            ids=id_list(get("id"), "id"), id_pattern=id_pattern(get("idPattern")), types=(entity_type,)
        )
    else:
        entities = entity_filter(params)

    if attr is not None:
        attrs: tuple[ValuePath, ...] | None = (parse_value_path(unescape_segment(attr)),)
    else:
        attrs = parse_attr_list(get("attrs"))

    last_n = positive(get("lastN"), "lastN")
    limit = page_limit(get("limit"), default_limit)
    offset = non_negative(get("offset"), "offset") or 0
    _no_options(get("options"))
    return HistoryQuery(
        shape=shape,
        scope=where,
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
    limit = page_limit(get("limit"), default_limit)
    return EntityListQuery(
        scope=scope(headers, tenant),
        entities=entity_filter(params),
        time=time_range(get("fromDate"), get("toDate")),
        limit=limit,
        offset=non_negative(get("offset"), "offset") or 0,
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
    where = scope(headers, tenant)
    if entity_id is not None:
        entity_id = _segment(entity_id, "entityId")
        entities = EntityFilter(ids=(entity_id,), types=id_list(get("type"), "type"))
    else:
        entity_type = _segment(entity_type or "", "entityType")
        entities = EntityFilter(types=(entity_type,))
    drop = get("dropTable")
    if drop is not None and drop.lower() not in ("true", "false"):
        raise BadRequest(f"dropTable must be true or false, not {drop[:40]!r}")
    return DeleteQuery(where, entities, time_range(get("fromDate"), get("toDate")))


# --- pieces ------------------------------------------------------------------------


def geo_filter(params: Mapping[str, str]) -> object | None:
    """``georel``, ``geometry`` and ``coords`` as a ``GeoFilter`` (or None);
    ``geoScope`` chooses sample (default) or entity semantics."""
    from tsdb_service.geo.filter import parse_geo

    return parse_geo(params.get("georel"), params.get("geometry"), params.get("coords"), params.get("geoScope"))


def _no_options(raw: str | None) -> None:
    if raw not in (None, ""):
        raise BadRequest(f"options={raw[:40]!r} is not supported", error="NotSupported")


def _segment(raw: str, name: str) -> str:
    """An entity id or type from a URL path segment."""
    value = unescape_segment(raw)
    check_id(value, name)
    return value
