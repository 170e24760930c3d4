"""One temporal read, from a ``TemporalQuery`` to the entities of the
response: match entities (``ngsild.fetch``), page them, read the page's
instances or aggregates, cut at the instance cap, render.

Runs in the threadpool (database calls, maybe a context fetch).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from datetime import datetime

from tsdb_service.core.errors import NonexistentTenant, ResourceNotFound
from tsdb_service.core.query import ANY_INSTANCE, InstanceRow, InstanceWindow, ValueTest
from tsdb_service.core.timefmt import ld_iso as iso
from tsdb_service.faces.ngsild import qlang, scope
from tsdb_service.faces.ngsild.aggregate import Aggregator
from tsdb_service.faces.ngsild.context import TermMap
from tsdb_service.faces.ngsild.fetch import EntityKey, Fetcher
from tsdb_service.faces.ngsild.params import uri
from tsdb_service.faces.ngsild.query import Format, TemporalQuery
from tsdb_service.faces.ngsild.render import Shape, aggregated, entity, normalized, simplified, value_of
from tsdb_service.read import TemporalReads
from tsdb_service.read.requests import InstancesRead

SCOPE_IRI = "https://uri.etsi.org/ngsi-ld/scope"  # the core context's scope


@dataclass(frozen=True)
class Cut:
    """An answer cut at the instance cap (206): ``content_range`` (clause
    6.3.10), and the window that continues it, ``(timerel, timeAt,
    endTimeAt)`` (None when more than the cap share one instant), named by
    the newer drafts' ``Link`` relation ``rel``: ``intervalafter``
    forwards, ``intervalbefore`` backwards with ``lastN``."""

    content_range: str
    rel: str
    window: tuple[str, datetime, datetime | None] | None


@dataclass
class TemporalResult:
    entities: list[dict]
    count: int  # entities matched, before paging
    cut: Cut | None = None  # set: the instances were cut (206)


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
    if query.entity_id is not None:
        return _retrieve(fetcher, query, by_entity, cap, terms)
    iris = fetcher.attr_iris([r for refs in by_entity.values() for r in refs])
    keys = _with_attrs(query, by_entity, iris)
    if query.scope_q is not None:
        keys = _in_scope(querier, query.scope_q, keys, by_entity, iris)
    # Whether each entity has an instance in the window is learnt from its
    # page's read when the page holds every match and shows every series
    # that decides it; otherwise it is asked first: with q's reads, or
    # without q and geo a few entities at a time, in order, until the page
    # and one more are found (all of them only for count=true).
    whole = query.offset == 0 and len(keys) <= query.limit and query.pick is None and query.omit is None
    ask = not whole and not _alive_implied(query)
    count = None
    if ask and query.q is None and query.geo is None and not query.count:
        keys, count = _first_alive(fetcher, query, keys, by_entity, iris)
    elif keys and (query.geo is not None or query.q is not None or ask):
        located_sids = None if located is None else located[1]
        alive = _alive(fetcher, query, by_entity, iris, keys) if ask else None
        keys = sorted(
            fetcher.matching(query, {k: by_entity[k] for k in keys}, iris, located_sids, alive),
            reverse=query.descending,
        )
    page_keys = keys[query.offset : query.offset + query.limit]
    selected = {key: fetcher.selected(query, by_entity[key], iris) for key in page_keys}
    rendered, cut = _read(querier, fetcher, query, selected, iris, cap)
    count = len(keys) if count is None else count
    if whole:
        empty = [key for key in page_keys if not rendered.get(key)]
        if empty and cut is not None:  # the cut may have emptied them: ask
            alive = _alive(fetcher, query, by_entity, iris, empty)
            living = fetcher.matching(
                replace(query, q=None, geo=None), {k: by_entity[k] for k in empty}, iris, None, alive
            )
            empty = [key for key in empty if key not in living]
        if empty:
            gone = set(empty)
            page_keys = [key for key in page_keys if key not in gone]
            count -= len(gone)
    return TemporalResult(_entities(query, page_keys, rendered, terms), count, cut)


FIRST_PROBE = 64  # entities asked about at first by _first_alive; doubled each round


def _first_alive(fetcher: Fetcher, query: TemporalQuery, keys: list[EntityKey], by_entity, iris):
    """The first ``offset + limit + 1`` of ``keys`` (in order) with an
    instance in the window, asked of a few entities at a time rather than
    of every entity of a type (a page of a 100,000-entity type would scan
    every instance of the window), and a count that is exact when every
    key was asked, else just past the page (so a next page is linked)."""
    need = query.offset + query.limit + 1
    found: list[EntityKey] = []
    start, size = 0, max(FIRST_PROBE, need)
    while start < len(keys) and len(found) < need:
        part = keys[start : start + size]
        start += size
        size *= 2
        living = fetcher.matching(
            query, {k: by_entity[k] for k in part}, iris, None, _alive(fetcher, query, by_entity, iris, part)
        )
        found.extend(k for k in part if k in living)
    return found, len(found)


def _retrieve(fetcher: Fetcher, query: TemporalQuery, by_entity, cap: int, terms: TermMap) -> TemporalResult:
    """One entity (``GET /temporal/entities/{id}``): 404 when it has no
    series, none of the attributes asked for, nothing left to show after
    ``pick``/``omit``, or no instance at all (it was deleted)."""
    what = f"no temporal evolution of entity {query.entity_id!r}"
    if not by_entity:
        uri(query.entity_id, "the entity id")  # an id no entity has: a 400 when it is no URI
        raise ResourceNotFound(what)
    all_refs = [r for refs in by_entity.values() for r in refs]
    iris = fetcher.attr_iris(all_refs)
    if query.attrs is not None and not any(iris[r.sid] in query.attrs for r in all_refs):
        raise ResourceNotFound(f"entity {query.entity_id!r} has none of the attributes {', '.join(query.attrs)}")
    keys = sorted(by_entity)
    if query.geo is not None or query.q is not None:
        keys = sorted(fetcher.matching(query, by_entity, iris))
        if not keys:
            raise ResourceNotFound(f"{what} matches q and the geo-query in the window")
    selected = {key: fetcher.selected(query, by_entity[key], iris) for key in keys}
    shown = {m for m in ("id", "type") if _shows(query, m)} | {iris[r.sid] for refs in selected.values() for r in refs}
    if not shown:
        raise ResourceNotFound(f"{what}: pick and omit leave no member of it")
    rendered, cut = _read(fetcher.q, fetcher, query, selected, iris, cap)
    if not any(rendered.values()) and not fetcher.q.sids_with_samples([r.sid for r in all_refs]):
        raise ResourceNotFound(what)
    return TemporalResult(_entities(query, keys, rendered, terms), len(keys), cut)


def _shows(query: TemporalQuery, member: str) -> bool:
    """Does the projection keep ``id`` or ``type``?"""
    return (query.pick is None or member in query.pick) and member not in (query.omit or ())


def _alive_implied(query: TemporalQuery) -> bool:
    """Does matching ``q`` or the geo-query already prove an instance in the
    window of a series ``_alive`` would ask about? A ``q`` without ``!``
    holds only through a holding term, which an instance of its attribute
    in the window satisfied; a geo-query, a location instance."""
    if query.dataset_ids is not None or (query.q is None and query.geo is None):
        return False
    attrs = None if query.attrs is None else set(query.attrs)
    q = query.q
    if q is not None and not qlang.negates(q) and (attrs is None or all(t.attr in attrs for t in qlang.terms(q))):
        return True
    return query.geo is not None and (attrs is None or query.geo.geoproperty in attrs)


def _alive(fetcher: Fetcher, query: TemporalQuery, by_entity, iris, keys) -> tuple[list[int], ValueTest]:
    """The series whose instances in the window make an entity part of a
    query's answer (those of ``attrs`` and ``datasetId``; ``pick`` and
    ``omit`` only shape it), and the test an instance must pass: any
    instance, or for aggregation one with a value (deletions are not
    aggregated)."""
    shaped = replace(query, pick=None, omit=None)
    sids = [r.sid for key in keys for r in fetcher.selected(shaped, by_entity[key], iris)]
    return sids, ValueTest(ANY_INSTANCE) if query.format is not Format.AGGREGATED else ValueTest()


def _read(querier: TemporalReads, fetcher: Fetcher, query: TemporalQuery, selected, iris, cap: int):
    """The page's instances or aggregates, rendered per entity (an entity
    without any in the window maps to ``{}``), and where they were cut."""
    sids = [r.sid for refs in selected.values() for r in refs]
    if query.format is Format.AGGREGATED:
        agg = query.aggregation
        assert agg is not None, "the parser gives format=aggregated its aggregation"
        periods = Aggregator(fetcher).run(sids, query.window, agg)
        return _aggregated(agg.methods, selected, iris, periods), None
    rows, cut = _instances(querier, query, sids, cap)
    return _instances_rendered(query, selected, iris, rows), cut


def _with_attrs(query: TemporalQuery, by_entity, iris) -> list[EntityKey]:
    """The entities in the query's order; with ``attrs``, those that have one of them."""
    keys = by_entity if query.attrs is None else _having(by_entity, iris, set(query.attrs))
    return sorted(keys, reverse=query.descending)


def _in_scope(querier: TemporalReads, expr, keys: list[EntityKey], by_entity, iris) -> list[EntityKey]:
    """Those of ``keys`` whose current scopes (their latest ``scope``
    instance, whatever the window) satisfy ``scopeQ``."""
    owner = {r.sid: key for key in keys for r in by_entity[key] if iris[r.sid] == SCOPE_IRI}
    latest: dict[EntityKey, InstanceRow] = {}
    for row in querier.temporal_instances(InstancesRead(list(owner), last_n=1)) if owner else ():
        key = owner[row.sid]
        if key not in latest or (row.at, row.iid) > (latest[key].at, latest[key].iid):
            latest[key] = row
    current = {key: value_of(row, "Property") for key, row in latest.items() if row.deleted_at is None}
    return [
        key
        for key in keys
        if isinstance(found := current.get(key), (str, list))
        and scope.holds(expr, [found] if isinstance(found, str) else found)
    ]


def _having(by_entity, iris, wanted: set[str]) -> list[EntityKey]:
    return [k for k, refs in by_entity.items() if any(iris[r.sid] in wanted for r in refs)]


def _instances(
    querier: TemporalReads, query: TemporalQuery, sids: list[int], cap: int
) -> tuple[list[InstanceRow], Cut | None]:
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
    whole = edge != first_out  # no instant was split: the rest is a window of its own
    if newest_first:
        start = w.end if w.end is not None else max(r.at for r in kept)
        size = str(query.last_n)
        rest = (("before", edge, None) if w.start is None else ("between", w.start, edge)) if whole else None
        rel = "intervalbefore"
    else:
        start = w.start if w.start is not None else min(r.at for r in kept)
        size = "*"
        rest = (("after", first_out, None) if w.end is None else ("between", first_out, w.end)) if whole else None
        rel = "intervalafter"
    return kept, Cut(f"date-time {iso(start)}-{iso(edge)}/{size}", rel, rest)


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
            out[key] = {iri: simplified(group, query.lang) for iri, group in attrs.items()}
        else:
            shape = Shape(query.sys_attrs, query.format is Format.CONCISE, query.lang)
            out[key] = {iri: normalized(group, shape) for iri, group in attrs.items()}
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
