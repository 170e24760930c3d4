"""One temporal read, from a ``TemporalQuery`` to the entities of the
response: match entities (``ngsild.fetch``), page them, read the page's
instances or aggregates, page the instances, render.

Instances are paged one of two ways, chosen by what the request uses
(``TemporalQuery.paged_by_rank``):

* **V1.9.1** (clause 6.3.10; ``lastN`` or no instance parameter): every
  instance of the window, at most the cap (``TSDB_NGSILD_MAX_INSTANCES``)
  in one answer; past it the answer is cut at one instant, 206 Partial
  Content with ``Content-Range`` (``Cut``);
* **TS 104 176** (clause 6.4.7.3; ``firstN``, ``offsetN``, or a link of
  ours): always 200; per attribute the oldest (``firstN``) or newest
  (``lastN``) N past ``offsetN``, as many per attribute as the cap allows;
  ``Link`` relations ``intervalafter`` (later instances) and
  ``intervalbefore`` (earlier ones) name the next pages (``PageLink``).
  The links carry ``storedThrough``: the largest instance id of the window
  when the walk began, so the ranks ``offsetN`` counts stay put while
  instances arrive (instance ids grow as instances are stored) and a walk
  neither skips nor repeats an instance.

``asOf`` (our extension) answers the state at an instant instead: each
attribute's latest instance at or before it, ``q``, ``scopeQ`` and the
geo-query judged on that state.

Runs in the threadpool (database calls, maybe a context fetch).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from datetime import UTC, datetime, timedelta
from itertools import groupby
from operator import attrgetter

from tsdb_service.core.budget import QueryTooLarge
from tsdb_service.core.errors import NonexistentTenant, ResourceNotFound, TooManyResults
from tsdb_service.core.query import ANY_INSTANCE, InstanceRow, InstanceWindow, ValueTest
from tsdb_service.core.timefmt import ld_iso as iso
from tsdb_service.faces.ngsild import qlang, scope
from tsdb_service.faces.ngsild.aggregate import Aggregator
from tsdb_service.faces.ngsild.context import TermMap
from tsdb_service.faces.ngsild.fetch import EntityKey, Fetcher, instance_window, is_relationship, term_value
from tsdb_service.faces.ngsild.params import uri
from tsdb_service.faces.ngsild.query import Format, TemporalQuery, Window
from tsdb_service.faces.ngsild.render import Shape, aggregated, entity, normalized, simplified, value_of
from tsdb_service.read import TemporalReads
from tsdb_service.read.requests import InstancePage, InstancesRead

SCOPE_IRI = "https://uri.etsi.org/ngsi-ld/scope"  # the core context's scope
_MICROSECOND = timedelta(microseconds=1)


@dataclass(frozen=True)
class Cut:
    """An answer cut at the instance cap (206, V1.9.1): ``content_range``
    (clause 6.3.10), and the window that continues it, ``(timerel, timeAt,
    endTimeAt)`` (None when more than the cap share one instant), named by
    the newer ``Link`` relation ``rel``: ``intervalafter`` forwards,
    ``intervalbefore`` backwards with ``lastN``."""

    content_range: str
    rel: str
    window: tuple[str, datetime, datetime | None] | None


@dataclass(frozen=True)
class PageLink:
    """A page of TS 104 176's temporal pagination (clause 6.4.7.3): ``rel``
    ``intervalafter`` holds later instances, ``intervalbefore`` earlier
    ones; ``params`` the query parameters that differ from the request's
    (``offsetN``, ``storedThrough``)."""

    rel: str
    params: tuple[tuple[str, str], ...]


@dataclass
class TemporalResult:
    entities: list[dict]
    count: int  # entities matched, before paging
    cut: Cut | None = None  # set: the instances were cut (206, V1.9.1)
    pages: list[PageLink] = field(default_factory=list)  # TS 104 176 links (or a lastN answer's earlier instances)


@dataclass(frozen=True)
class _Read:
    """A page's rendering: entity → attribute IRI → its rendering (``{}``
    for an entity without instances on the page), and how it was paged."""

    rendered: dict[EntityKey, dict[str, object]]
    cut: Cut | None = None
    pages: tuple[PageLink, ...] = ()
    partial: bool = False  # an entity may have instances in the window that the page does not show


def run(
    querier: TemporalReads, terms: TermMap, query: TemporalQuery, cap: int, *, tell_tenants: bool = True
) -> TemporalResult:
    """``tell_tenants=False`` (authentication on): a tenant without data
    answers as one without matching entities, so the answer does not tell
    a caller which tenants exist."""
    fetcher = Fetcher(querier, terms)
    if tell_tenants and query.tenant and query.tenant not in querier.tenants():
        raise NonexistentTenant(f"tenant {query.tenant!r} has no data")
    if query.as_of is not None:
        query = replace(query, window=Window("before", None, query.as_of + _MICROSECOND, query.window.timeproperty))
    located = fetcher.located(query)
    by_entity = located[0] if located is not None else fetcher.series(query)
    _check_ids(query, by_entity)
    if query.entity_id is not None:
        return _retrieve(fetcher, query, by_entity, cap, terms)
    iris = fetcher.attr_iris([r for refs in by_entity.values() for r in refs])
    keys = _with_attrs(query, by_entity, iris)
    if query.scope_q is not None:
        keys, query = _in_scope(querier, query, keys, by_entity, iris)
    if query.as_of is not None:
        return _as_of(fetcher, query, keys, by_entity, iris, terms)
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
    read = _read(querier, fetcher, query, selected, iris, cap)
    rendered = read.rendered
    count = len(keys) if count is None else count
    if whole:
        empty = [key for key in page_keys if not rendered.get(key)]
        if empty and read.partial:  # the page's read may have left them out: ask
            alive = _alive(fetcher, query, by_entity, iris, empty)
            living = fetcher.matching(
                replace(query, q=None, geo=None), {k: by_entity[k] for k in empty}, iris, None, alive
            )
            empty = [key for key in empty if key not in living]
        if empty:
            gone = set(empty)
            page_keys = [key for key in page_keys if key not in gone]
            count -= len(gone)
    entities = _entities(query, page_keys, rendered, terms, fetcher.types)
    return TemporalResult(entities, count, read.cut, list(read.pages))


def _check_ids(query: TemporalQuery, by_entity) -> None:
    """An entity id that no stored entity has must be a URI (clause 4.5.1):
    else the request names no entity at all, a 400 (NGSIv2 data keeps its
    ids, URIs or not, so a stored one is found whatever it is)."""
    asked = [i for s in query.selectors for i in s.ids or ()]
    if not asked:
        return
    stored = {key[0] for key in by_entity}
    for ident in asked:
        if ident not in stored:
            uri(ident, "an entity id")


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
    if query.scope_q is not None:
        keys, query = _in_scope(fetcher.q, query, keys, by_entity, iris)
        if not keys:
            raise ResourceNotFound(f"{what} matches scopeQ in the window")
    selected = {key: fetcher.selected(query, by_entity[key], iris) for key in keys}
    shown = {m for m in ("id", "type") if _shows(query, m)} | {iris[r.sid] for refs in selected.values() for r in refs}
    if not shown:
        raise ResourceNotFound(f"{what}: pick and omit leave no member of it")
    if query.as_of is not None:
        state = _state(fetcher, query, by_entity, iris, keys)
        if (query.geo is not None or query.q is not None) and not state.matching(query, keys):
            raise ResourceNotFound(f"{what} matches q and the geo-query at {iso(query.as_of)}")
        rendered = _instances_rendered(query, selected, iris, state.rows)
        return TemporalResult(_entities(query, keys, rendered, terms, fetcher.types), len(keys))
    if query.geo is not None or query.q is not None:
        keys = sorted(fetcher.matching(query, {k: by_entity[k] for k in keys}, iris))
        if not keys:
            raise ResourceNotFound(f"{what} matches q and the geo-query in the window")
        selected = {key: selected[key] for key in keys}
    read = _read(fetcher.q, fetcher, query, selected, iris, cap)
    if not any(read.rendered.values()) and not fetcher.q.sids_with_samples([r.sid for r in all_refs]):
        raise ResourceNotFound(what)
    entities = _entities(query, keys, read.rendered, terms, fetcher.types)
    return TemporalResult(entities, len(keys), read.cut, list(read.pages))


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


def _read(querier: TemporalReads, fetcher: Fetcher, query: TemporalQuery, selected, iris, cap: int) -> _Read:
    """The page's instances or aggregates, rendered per entity, and how
    they were paged."""
    sids = [r.sid for refs in selected.values() for r in refs]
    if query.format is Format.AGGREGATED:
        agg = query.aggregation
        assert agg is not None, "the parser gives format=aggregated its aggregation"
        periods = Aggregator(fetcher).run(sids, query.window, agg)
        return _Read(_aggregated(agg.methods, selected, iris, periods))
    if query.paged_by_rank:
        rows, pages = _ranked(querier, query, sids, cap)
        partial = bool(query.offset_n) or query.stored_through is not None
        return _Read(_instances_rendered(query, selected, iris, rows), pages=tuple(pages), partial=partial)
    if query.last_n is not None:
        newest = _newest(querier, query, sids, cap)
        if newest is not None:
            rows, pages = newest
            return _Read(_instances_rendered(query, selected, iris, rows), pages=tuple(pages))
    rows, cut = _instances(querier, query, sids, cap)
    return _Read(_instances_rendered(query, selected, iris, rows), cut, partial=cut is not None)


def _with_attrs(query: TemporalQuery, by_entity, iris) -> list[EntityKey]:
    """The entities in the query's order; with ``attrs``, those that have one of them."""
    keys = by_entity if query.attrs is None else _having(by_entity, iris, set(query.attrs))
    return sorted(keys, reverse=query.descending)


def _having(by_entity, iris, wanted: set[str]) -> list[EntityKey]:
    return [k for k, refs in by_entity.items() if any(iris[r.sid] in wanted for r in refs)]


# -- scopeQ over time (clauses 4.18, 4.19) ------------------------------------------------------


def _in_scope(querier: TemporalReads, query: TemporalQuery, keys: list[EntityKey], by_entity, iris):
    """Those of ``keys`` whose scope matched ``scopeQ`` during the window,
    and the query with its window narrowed, for each entity whose scope
    matched only part of it, to when it did (``Window.spans``): a scope
    replaced mid-window bounds the instances each scope matches.

    An entity's scopes are the values of its ``scope`` instances; each holds
    from its instance's time to the next one's (a deletion: none from
    then on); the first holds from the start of time (a scope is given when
    an entity is created, usually after its first observations were made).
    With ``asOf``, the scope at that instant decides."""
    assert query.scope_q is not None
    owner = {r.sid: key for key in keys for r in by_entity[key] if iris[r.sid] == SCOPE_IRI}
    changes = _scope_changes(querier, query.window, list(owner))
    w = query.window
    kept: list[EntityKey] = []
    spans: list[tuple[int, datetime | None, datetime | None]] = list(w.spans)
    for key, rows in groupby(sorted(changes, key=lambda r: owner[r.sid]), key=lambda r: owner[r.sid]):
        matched = _matching_spans(query.scope_q, sorted(rows, key=attrgetter("at", "iid")))
        if query.as_of is not None:
            at = query.as_of.astimezone(UTC).replace(tzinfo=None)
            if any((a is None or a <= at) and (b is None or at < b) for a, b in matched):
                kept.append(key)
            continue
        inside = _clipped(matched, _naive(w.start), _naive(w.end))
        if not inside:
            continue
        kept.append(key)
        if not (len(inside) == 1 and inside[0] == (_naive(w.start), _naive(w.end))):
            spans += [(ref.sid, _aware(a), _aware(b)) for ref in by_entity[key] for a, b in inside]
    order = {key: i for i, key in enumerate(keys)}
    kept.sort(key=order.__getitem__)
    return kept, replace(query, window=replace(w, spans=tuple(spans)))


MAX_SCOPE_CHANGES = 10_000  # scope instances one query may read


def _scope_changes(querier: TemporalReads, w: Window, sids: list[int]) -> list[InstanceRow]:
    """The scope instances that decide the window: the last before it, and
    those in it (at most ``MAX_SCOPE_CHANGES``)."""
    if not sids:
        return []
    tp = w.timeproperty.value
    rows: list[InstanceRow] = []
    if w.start is not None:
        rows += querier.temporal_instances(InstancesRead(sids, InstanceWindow(tp, None, w.start), last_n=1))
    inside = querier.temporal_instances(
        InstancesRead(sids, InstanceWindow(tp, w.start, w.end), limit=MAX_SCOPE_CHANGES + 1)
    )
    if len(inside) > MAX_SCOPE_CHANGES:
        raise QueryTooLarge(
            f"scopeQ: the entities' scopes change more than {MAX_SCOPE_CHANGES} times in the window; narrow it"
        )
    return rows + inside


def _matching_spans(expr, rows: list[InstanceRow]) -> list[tuple[datetime | None, datetime | None]]:
    """The spans of time (naive UTC, None: open) during which an entity's
    scope (its ``scope`` instances ``rows``, in time order) satisfied ``expr``."""
    out: list[tuple[datetime | None, datetime | None]] = []
    for i, row in enumerate(rows):
        value = value_of(row, "Property")
        scopes = [value] if isinstance(value, str) else value
        if row.deleted_at is not None or not isinstance(scopes, list) or not scope.holds(expr, scopes):
            continue
        start = None if i == 0 else row.at
        end = rows[i + 1].at if i + 1 < len(rows) else None
        if out and out[-1][1] == start:
            out[-1] = (out[-1][0], end)
        else:
            out.append((start, end))
    return out


def _clipped(spans, start: datetime | None, end: datetime | None) -> list[tuple[datetime | None, datetime | None]]:
    """``spans`` within [start, end) (None: open), the empty ones left out."""
    out = []
    for a, b in spans:
        lo = a if start is None or (a is not None and a > start) else start
        hi = b if end is None or (b is not None and b < end) else end
        if lo is None or hi is None or lo < hi:
            out.append((lo, hi))
    return out


def _naive(moment: datetime | None) -> datetime | None:
    """A window's (aware) bound as instance times are: naive UTC."""
    if moment is None or moment.tzinfo is None:
        return moment
    return moment.astimezone(UTC).replace(tzinfo=None)


def _aware(moment: datetime | None) -> datetime | None:
    """An instance time (naive UTC) as a window's bound."""
    return None if moment is None else moment.replace(tzinfo=UTC)


# -- asOf: the state at an instant (our extension) -----------------------------------------------


@dataclass(frozen=True)
class _State:
    """Each series' latest instance at or before the instant (one
    ``temporal_instances`` read with ``last_n=1``), and the series of each
    entity by attribute IRI, to judge ``q`` and the geo-query on."""

    rows: list[InstanceRow]
    by_entity: dict[EntityKey, dict[str, list[int]]]

    def matching(self, query: TemporalQuery, keys: list[EntityKey]) -> list[EntityKey]:
        """Those of ``keys`` whose state satisfies ``q`` and the geo-query:
        a term holds when the latest instance of one of its attribute's
        series (any datasetId) satisfies it."""
        latest = {row.sid: row for row in self.rows}
        out = []
        for key in keys:
            series = self.by_entity.get(key, {})

            def state(iri: str, series=series) -> list[InstanceRow | None]:
                return [latest.get(sid) for sid in series.get(iri, [])]

            if query.geo is not None and not _located(query, state(query.geo.geoproperty)):
                continue
            if query.q is not None and not qlang.evaluate(query.q, lambda term: _state_holds(term, state(term.attr))):
                continue
            out.append(key)
        return out


def _state_holds(term: qlang.Term, rows: list[InstanceRow | None]) -> bool:
    for row in rows:
        if row is None or row.deleted_at is not None:
            continue
        if term.op in qlang.ORDERING and is_relationship(term, row.kind, row.md):
            continue  # an ordering operator never matches a Relationship (clause 4.9)
        if term.matches(term_value(term, row.kind, row.num, row.txt, row.js, row.md)):
            return True
    return False


def _located(query: TemporalQuery, rows: list[InstanceRow | None]) -> bool:
    assert query.geo is not None
    shapes = [row.js for row in rows if row is not None and row.deleted_at is None and row.js]
    return bool(shapes) and any(query.geo.filter.matching(shapes))


def _state(fetcher: Fetcher, query: TemporalQuery, by_entity, iris, keys: list[EntityKey]) -> _State:
    """The latest instance at or before the instant (``as_of``) of every series of
    ``keys`` (one statement; one row per series: bounded by the series
    budget)."""
    sids = [r.sid for key in keys for r in by_entity[key]]
    rows = fetcher.q.temporal_instances(InstancesRead(sids, instance_window(query.window), last_n=1)) if sids else []
    grouped: dict[EntityKey, dict[str, list[int]]] = {}
    for key in keys:
        for ref in by_entity[key]:
            grouped.setdefault(key, {}).setdefault(iris[ref.sid], []).append(ref.sid)
    return _State(rows, grouped)


def _as_of(fetcher: Fetcher, query: TemporalQuery, keys, by_entity, iris, terms: TermMap) -> TemporalResult:
    """Every matched entity as it was at the instant (``as_of``): each attribute's
    latest instance at or before it (the instance a ``lastN=1`` over
    ``timerel=before`` just past the instant gives), in the query's
    representation; the entities that had an instance by then, those
    whose state then satisfies ``q`` and the geo-query, paged by id."""
    state = _state(fetcher, query, by_entity, iris, keys)
    living = {row.sid for row in state.rows}
    shaped = replace(query, pick=None, omit=None)
    keys = [key for key in keys if any(r.sid in living for r in fetcher.selected(shaped, by_entity[key], iris))]
    if query.q is not None or query.geo is not None:
        keys = state.matching(query, keys)
    page_keys = keys[query.offset : query.offset + query.limit]
    selected = {key: fetcher.selected(query, by_entity[key], iris) for key in page_keys}
    rendered = _instances_rendered(query, selected, iris, state.rows)
    return TemporalResult(_entities(query, page_keys, rendered, terms, fetcher.types), len(keys))


# -- instances, V1.9.1's way (clause 6.3.10) ------------------------------------------------------


def _instances(
    querier: TemporalReads, query: TemporalQuery, sids: list[int], cap: int
) -> tuple[list[InstanceRow], Cut | None]:
    """The page's instances, at most ``cap``; past it, cut at one instant
    so no attribute is left with a gap, and say which span was served."""
    w = query.window
    window = instance_window(w)
    newest_first = query.last_n is not None
    rows = querier.temporal_instances(
        InstancesRead(sids, window, last_n=query.last_n, limit=cap + 1, newest_first=newest_first)
    )
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


def _newest(
    querier: TemporalReads, query: TemporalQuery, sids: list[int], cap: int
) -> tuple[list[InstanceRow], list[PageLink]] | None:
    """A ``lastN`` answer that fits the cap, read by rank (one statement:
    each series' N newest and one more): the N newest of each series, and
    when some series has more, the link to the earlier instances that the
    newer binding gives (TS 104 176 clause 6.4.7.3: ``intervalbefore``,
    ``offsetN=N``, held to the instances stored now; V1.9.1 clients ignore
    a relation they do not know). None when the answer does not fit:
    V1.9.1's cut (206) then reads by time."""
    assert query.last_n is not None
    n, series = query.last_n, len(set(sids))
    if not series:
        return [], []
    limit = cap + series + 1
    ask = InstancePage(sids, instance_window(query.window), False, 0, n + 1, limit)
    rows, top = querier.instance_page(ask)
    ranks = _ranks(rows, ascending=False)
    kept = [row for row in rows if ranks[(row.sid, row.iid)] <= n]
    if len(rows) >= limit or len(kept) > cap:
        return None
    if len(kept) == len(rows) or top is None:
        return kept, []
    return kept, [PageLink("intervalbefore", (("offsetN", str(n)), ("storedThrough", str(top))))]


# -- instances, TS 104 176's way (clause 6.4.7.3) ---------------------------------------------------


def _ranked(
    querier: TemporalReads, query: TemporalQuery, sids: list[int], cap: int
) -> tuple[list[InstanceRow], list[PageLink]]:
    """Per series (attribute and datasetId) the instances ranked past
    ``offsetN``, oldest first (``firstN``, or neither) or newest first
    (``lastN``), N of them (the cap without ``firstN``/``lastN``), each
    series independently. When N per series would pass the cap in all,
    every series gets the K that fit (the k-th instance of every series
    before any (k+1)-th), and the links go on from ``offsetN + K``."""
    ascending = query.last_n is None
    size = query.first_n or query.last_n or cap
    offset = query.offset_n or 0
    series = len(set(sids))
    if not series:
        return [], []
    limit = cap + series + 1  # every complete rank up to the cap, and the next one: is there more?
    ask = InstancePage(sids, instance_window(query.window), ascending, offset, size + 1, limit, query.stored_through)
    rows, top = querier.instance_page(ask)
    ranks = _ranks(rows, ascending)
    per_rank = [0] * (max(ranks.values(), default=0) + 1)
    for rank in ranks.values():
        per_rank[rank] += 1
    complete = len(per_rank) - 1 if len(rows) < limit else len(per_rank) - 2  # the last rank read may be cut
    served, total = 0, 0
    for rank in range(1, min(size, complete) + 1):
        if total + per_rank[rank] > cap:
            break
        total += per_rank[rank]
        served = rank
    if rows and served == 0:
        raise TooManyResults(
            f"one instance of each of the {series} attributes asked for is more than the {cap} instances one answer "
            "may hold (TSDB_NGSILD_MAX_INSTANCES): ask for fewer entities (limit) or attributes (attrs)"
        )
    kept = [row for row in rows if ranks[(row.sid, row.iid)] <= served]
    return kept, _page_links(query, ascending, size, offset, served, top, more=len(kept) < len(rows))


def _ranks(rows: list[InstanceRow], ascending: bool) -> dict[tuple[int, int], int]:
    """Each row's rank within its series on the page (1: the first past the offset)."""
    out: dict[tuple[int, int], int] = {}
    for sid, group in groupby(rows, key=attrgetter("sid")):  # rows come sorted by series, then time
        ordered = list(group)
        if not ascending:
            ordered.reverse()
        for rank, row in enumerate(ordered, start=1):
            out[(sid, row.iid)] = rank
    return out


def _page_links(
    query: TemporalQuery, ascending: bool, size: int, offset: int, served: int, top: int | None, more: bool
) -> list[PageLink]:
    """``intervalafter`` holds later instances, ``intervalbefore`` earlier
    ones (the relations are about time, so they swap with the direction):
    the deeper page when some series has more, the shallower one past the
    first page, both held to the instances of ``top``."""
    through = (("storedThrough", str(top)),) if top is not None else ()
    deeper, shallower = ("intervalafter", "intervalbefore") if ascending else ("intervalbefore", "intervalafter")
    out = []
    if more:
        out.append(PageLink(deeper, (("offsetN", str(offset + served)), *through)))
    if offset > 0:
        out.append(PageLink(shallower, (("offsetN", str(max(0, offset - size))), *through)))
    return out


# -- rendering --------------------------------------------------------------------------------------


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


def _entities(
    query: TemporalQuery, page_keys: list[EntityKey], rendered, terms: TermMap, types: dict[str, tuple[str, ...]]
) -> list[dict]:
    """Entities of the page in order, each with all its types (every type
    its id was stored under: clause 4.16)."""
    compact = terms.compact
    out = []
    for key in page_keys:
        type_names = [compact(t) for t in terms.expand_all(list(types.get(key[0], (key[1],))))]
        out.append(entity(key[0], type_names, rendered.get(key, {}), query.pick, query.omit, compact))
    return out
