"""History results → QuantumLeap 1.0 JSON.

One function per endpoint family, named after QuantumLeap's handlers. Keys
are ``id``/``type`` (not the pre-1.0 ``entityId``/``entityType``); ``index``
and ``values`` are parallel arrays; ``attributes`` are sorted by name; time
strings are UTC with milliseconds, ``2024-05-01T10:00:00.123+00:00``, the
format QuantumLeap 1.0 answers with. An empty result is ``[]``.

For ``aggrScope=global`` one group stands for every matched entity: it
carries ``ids`` (and, on ``/v2/attrs``, ``types``) instead of ``id``/``type``.
"""

from __future__ import annotations

from typing import TypeVar

from tsdb_service.core.query import AggrScope, HistoryQuery, Shape
from tsdb_service.core.timefmt import iso_ms
from tsdb_service.history.service import EntityResult, HistoryResult

T = TypeVar("T")


def render(result: HistoryResult):
    if not result.entities:
        return []
    q = result.query
    return _RENDERERS[q.shape](q, result.entities)


def _index(q: HistoryQuery, ent: EntityResult, span: bool) -> list:
    """An entity's ``index``. Aggregated without ``aggrPeriod`` there is one
    value per entity and no time to give: QuantumLeap answers ``[]`` where
    ``span`` is false, else ``[fromDate, toDate]`` with ``""`` for a bound not
    given. We give the span only when both bounds were given, else ``[]``:
    an index never holds an empty string."""
    agg = q.aggregation
    if agg is not None and agg.period is None:
        if span and q.time.start is not None and q.time.end is not None:
            return [iso_ms(q.time.start), iso_ms(q.time.end)]
        return []
    return ent.index


def _listed(q: HistoryQuery, ent: EntityResult) -> bool:
    """On /v2/types/{type}/attrs/{attr} QuantumLeap gives the time span only
    to the entities named in ``id`` (a global group stands for all of them)."""
    if q.entities.ids is None:
        return False
    return _global(q) or ent.entity_id in q.entities.ids


def _global(q: HistoryQuery) -> bool:
    return q.aggregation is not None and q.aggregation.scope is AggrScope.GLOBAL


def _attributes(ent: EntityResult) -> list[dict]:
    return [{"attrName": name, "values": ent.columns[name]} for name in sorted(ent.columns)]


def _attr_name(q: HistoryQuery) -> str:
    """The attribute of a one-attribute route (its path names it)."""
    return _first(q.attrs).text


def _first(items: tuple[T, ...] | None) -> T:
    """The path segment a one-entity-type or one-attribute route was given:
    always there on those routes, so a missing one is a bug, not a 400."""
    if not items:
        raise AssertionError("a route with a path segment built a query without it")
    return items[0]


def _entity_attr(q: HistoryQuery, entities: list[EntityResult]):
    ent = entities[0]
    name = _attr_name(q)
    values = ent.columns.get(name, [])
    if q.values_only:
        return {"index": _index(q, ent, False), "values": values}
    return {
        "id": ent.entity_id,
        "type": ent.entity_type,
        "attrName": name,
        "index": _index(q, ent, False),
        "values": values,
    }


def _entity(q: HistoryQuery, entities: list[EntityResult]):
    ent = entities[0]
    if q.values_only:
        return {"index": _index(q, ent, False), "attributes": _attributes(ent)}
    return {
        "id": ent.entity_id,
        "type": ent.entity_type,
        "index": _index(q, ent, False),
        "attributes": _attributes(ent),
    }


def _head(q: HistoryQuery, ent: EntityResult) -> dict:
    if _global(q):
        return {"ids": ent.ids}
    return {"id": ent.entity_id}


def _type_attr(q: HistoryQuery, entities: list[EntityResult]):
    name = _attr_name(q)
    items = []
    for ent in entities:
        item = _head(q, ent)
        item["index"] = _index(q, ent, _listed(q, ent))
        item["values"] = ent.columns.get(name, [])
        items.append(item)
    if q.values_only:
        return {"values": items}
    return {"type": _first(q.entities.types), "attrName": name, "entities": items}


def _type(q: HistoryQuery, entities: list[EntityResult]):
    items = []
    for ent in entities:
        item = _head(q, ent)
        item["index"] = _index(q, ent, True)
        item["attributes"] = _attributes(ent)
        items.append(item)
    if q.values_only:
        return {"values": items}
    return {"type": _first(q.entities.types), "entities": items}


def _types_of(q: HistoryQuery, entities: list[EntityResult], column: str) -> list[dict]:
    """Entities that have ``column``, grouped by type (types by name)."""
    groups: dict[str, list] = {}
    heads: dict[str, dict] = {}
    for ent in entities:
        values = ent.columns.get(column)
        if values is None:
            continue
        if _global(q):
            key = ""
            ids, types = (ent.column_members or {}).get(column, (ent.ids, ent.types))
            heads[key] = {"types": types}
            item = {"ids": ids}
        else:
            key = ent.entity_type
            heads[key] = {"type": key}
            item = _head(q, ent)
        item["index"] = _index(q, ent, True)
        item["values"] = values
        groups.setdefault(key, []).append(item)
    # ``entities`` come type after type (history.service orders them).
    return [{**heads[key], "entities": groups[key]} for key in groups]


def _attr(q: HistoryQuery, entities: list[EntityResult]):
    name = _attr_name(q)
    types = _types_of(q, entities, name)
    if not types:
        return []
    if q.values_only:
        return {"values": types}
    return {"attrName": name, "types": types}


def _attrs(q: HistoryQuery, entities: list[EntityResult]):
    # QuantumLeap's order: each entity's attributes by name, entity after entity.
    names = list(dict.fromkeys(name for ent in entities for name in sorted(ent.columns)))
    items = [{"attrName": name, "types": _types_of(q, entities, name)} for name in names]
    if not items:
        return []
    if q.values_only:
        return {"values": items}
    return {"attrs": items}


_RENDERERS = {
    Shape.ENTITY_ATTR: _entity_attr,
    Shape.ENTITY: _entity,
    Shape.TYPE_ATTR: _type_attr,
    Shape.TYPE: _type,
    Shape.ATTR: _attr,
    Shape.ATTRS: _attrs,
}
