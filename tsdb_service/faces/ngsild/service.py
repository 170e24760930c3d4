"""One temporal read, from a ``TemporalQuery`` to the entities of the
response: match entities (``ngsild.fetch``), page them, read the page's
instances or aggregates, cut at the instance cap, render.

Runs in the threadpool (database calls, maybe a context fetch).
"""

from __future__ import annotations

from dataclasses import dataclass

from tsdb_service.core.errors import NonexistentTenant, ResourceNotFound
from tsdb_service.core.query import InstanceRow, InstanceWindow
from tsdb_service.core.timefmt import ld_iso as iso
from tsdb_service.faces.ngsild.aggregate import Aggregator
from tsdb_service.faces.ngsild.context import TermMap
from tsdb_service.faces.ngsild.fetch import EntityKey, Fetcher
from tsdb_service.faces.ngsild.query import Format, TemporalQuery
from tsdb_service.faces.ngsild.render import aggregated, entity, normalized, simplified
from tsdb_service.read import TemporalReads
from tsdb_service.read.requests import InstancesRead


@dataclass
class TemporalResult:
    entities: list[dict]
    count: int  # entities matched, before paging
    content_range: str | None = None  # set: the instances were cut (206)


def run(
    querier: TemporalReads, terms: TermMap, query: TemporalQuery, cap: int, *, tell_tenants: bool = True
) -> TemporalResult:
    """``tell_tenants=False`` (authentication on): a tenant without data
    answers as one without matching entities, so the answer does not tell
    a caller which tenants exist."""
    fetcher = Fetcher(querier, terms)
    if tell_tenants and query.tenant and query.tenant not in querier.tenants():
        raise NonexistentTenant(f"tenant {query.tenant!r} has no data")
    located = fetcher.located(query)
    by_entity = located[0] if located is not None else fetcher.series(query)
    if query.entity_id is not None and not by_entity:
        raise ResourceNotFound(f"no temporal evolution of entity {query.entity_id!r}")
    all_refs = [r for refs in by_entity.values() for r in refs]
    iris = fetcher.attr_iris(all_refs)
    keys = _matching(fetcher, query, by_entity, iris, None if located is None else located[1])
    page_keys = keys if query.entity_id is not None else keys[query.offset : query.offset + query.limit]
    selected = {key: fetcher.selected(query, by_entity[key], iris) for key in page_keys}
    sids = [r.sid for refs in selected.values() for r in refs]
    content_range = None
    if query.format is Format.AGGREGATED:
        agg = query.aggregation
        assert agg is not None, "the parser gives format=aggregated its aggregation"
        periods = Aggregator(fetcher).run(sids, query.window, agg)
        rendered = _aggregated(agg.methods, selected, iris, periods)
    else:
        rows, content_range = _instances(querier, query, sids, cap)
        rendered = _instances_rendered(query, selected, iris, rows)
    entities = _entities(query, page_keys, rendered, terms)
    return TemporalResult(entities, len(keys), content_range)


def _matching(fetcher: Fetcher, query: TemporalQuery, by_entity, iris, located: list[int] | None) -> list[EntityKey]:
    keys = set(by_entity)
    if query.attrs is not None and query.entity_id is None:
        wanted = set(query.attrs)
        keys = {k for k in keys if any(iris[r.sid] in wanted for r in by_entity[k])}
    if (query.geo is not None or query.q is not None) and keys:
        keys = fetcher.matching(query, {k: by_entity[k] for k in keys}, iris, located)
    return sorted(keys)


def _instances(
    querier: TemporalReads, query: TemporalQuery, sids: list[int], cap: int
) -> tuple[list[InstanceRow], str | None]:
    """The page's instances, at most ``cap``; past it, cut at one instant
    so no attribute is left with a gap, and say which span was served."""
    w = query.window
    window = InstanceWindow(w.timeproperty.value, w.start, w.end)
    newest_first = query.last_n is not None
    rows = querier.temporal_instances(
        InstancesRead(sids, window, last_n=query.last_n, limit=cap + 1, newest_first=newest_first)
    )
    if query.first_n is not None:
        rows = _first_n(rows, query.first_n)
    if len(rows) <= cap:
        return rows, None
    ordered = sorted(rows, key=lambda r: (r.at, r.iid), reverse=newest_first)
    first_out = ordered[cap].at
    kept = [r for r in ordered[:cap] if r.at != first_out] or ordered[:cap]
    edge = kept[-1].at
    if newest_first:
        start = w.end if w.end is not None else max(r.at for r in kept)
        size = str(query.last_n)
    else:
        start = w.start if w.start is not None else min(r.at for r in kept)
        size = "*"
    content_range = f"date-time {iso(start)}-{iso(edge)}/{size}"
    return kept, content_range


def _first_n(rows, n: int) -> list:
    """The oldest ``n`` of each series (rows come sorted by series, then time)."""
    seen: dict[int, int] = {}
    out = []
    for row in rows:
        seen[row.sid] = seen.get(row.sid, 0) + 1
        if seen[row.sid] <= n:
            out.append(row)
    return out


def _instances_rendered(query: TemporalQuery, selected, iris, rows) -> dict[EntityKey, dict[str, object]]:
    by_sid: dict[int, list] = {}
    for row in rows:
        by_sid.setdefault(row.sid, []).append(row)
    out: dict[EntityKey, dict[str, object]] = {}
    for key, refs in selected.items():
        attrs: dict[str, list] = {}
        for ref in refs:
            if ref.sid in by_sid:
                attrs.setdefault(iris[ref.sid], []).extend(by_sid[ref.sid])
        if query.format is Format.TEMPORAL_VALUES:
            out[key] = {iri: simplified(group) for iri, group in attrs.items()}
        else:
            out[key] = {iri: normalized(group, query.sys_attrs) for iri, group in attrs.items()}
    return out


def _aggregated(methods: tuple[str, ...], selected, iris, periods) -> dict[EntityKey, dict[str, object]]:
    out: dict[EntityKey, dict[str, object]] = {}
    for key, refs in selected.items():
        attrs: dict[str, list] = {}
        for ref in refs:
            series = periods.get(ref.sid)
            if series is not None:
                attrs.setdefault(iris[ref.sid], []).append((ref.dataset_id, series.attr_type, series.values))
        out[key] = {iri: aggregated(series, methods) for iri, series in attrs.items()}
    return out


def _entities(query: TemporalQuery, page_keys: list[EntityKey], rendered, terms: TermMap) -> list[dict]:
    """Entities of the page in order; one id with several stored types is
    one entity with those types (retrieve) or one per type (query)."""
    compact = terms.compact
    if query.entity_id is not None and page_keys:
        types = sorted({k[1] for k in page_keys})
        merged: dict[str, object] = {}
        for key in page_keys:
            merged.update(rendered.get(key, {}))
        type_names = [compact(t) for t in terms.expand_all(types)]
        return [entity(query.entity_id, type_names, merged, query.pick, query.omit, compact)]
    out = []
    for key in page_keys:
        type_name = compact(terms.expand(key[1]))
        out.append(entity(key[0], [type_name], rendered.get(key, {}), query.pick, query.omit, compact))
    return out
