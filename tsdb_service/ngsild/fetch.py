"""Running a ``TemporalQuery`` against the store: which entities, then
their instances, in as few SQL statements as the question allows.

Names: the store keeps attribute and type names as they were notified
(compacted by the broker, usually with the same @context clients use), so
a stored name is read as a term of the *request's* @context and expanded
with it; a stored full IRI stays itself. A request's names match stored
ones when their IRIs are equal, and responses compact them back.

Steps:

1. Series from the in-memory catalog: entity ids / idPattern, types (type
   expressions), attributes, datasetIds. No sample is read.
2. ``q`` and the geo-query, when given, each need a look at the instances
   in the window: a comparison on numbers or text is decided by the
   database (``Querier.instances_matching``), anything else reads the
   candidate values (``Querier.instance_values``); a geo-query reads the
   locations whose stored box passes its prefilter
   (``Querier.location_instances``) and applies the exact, geodesic
   predicate in Python.
3. The matching entities are sorted by id (then type) and paged.
4. Only the page's series are read (``ngsild.service``): instances in the
   window through ``Querier.temporal_instances`` (``lastN`` per series, at
   most ``cap + 1`` so a cut is detected: 206), or one grouped aggregation
   statement (``ngsild.aggregate``, ``Querier.instance_aggregate``). The
   SQL of each is rendered in storage (``storage.temporal``).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from functools import partial
from itertools import compress
from operator import attrgetter

import orjson

from ..query import VALUE_TEST_OPS, EntityFilter, InstanceWindow, Scope, SeriesRef, ValueTest
from ..storage.base import Querier
from . import qlang
from .context import TermMap
from .query import DEFAULT_DATASET, TemporalQuery, TypeExpr, TypeName, Window, type_matches

EntityKey = tuple[str, str]  # (entity id, stored entity type)
_SID = attrgetter("sid")


class Fetcher:
    """Answers one query's questions through the read seam (``storage.base.Querier``)."""

    def __init__(self, querier: Querier, terms: TermMap):
        self.q = querier
        self.terms = terms

    # -- 1. series ---------------------------------------------------------------

    def series(self, query: TemporalQuery) -> dict[EntityKey, list[SeriesRef]]:
        """Every selected series, grouped by entity; attributes and datasetIds
        narrowed, entities kept even when none of their attributes is selected
        (they still match; their attributes are empty)."""
        scope = Scope(query.tenant)
        refs: list[SeriesRef] = []
        for selector in query.selectors:
            ids = (query.entity_id,) if query.entity_id is not None else selector.ids
            found = self.q.series(scope, EntityFilter(ids=ids, id_pattern=selector.id_pattern))
            if selector.types is not None:
                types = {r.entity_type for r in found}
                ok = self._types_taken(selector.types, types)
                if ok != types:
                    found = [r for r in found if r.entity_type in ok]
            refs.extend(found)
        if len(query.selectors) > 1:  # alternatives may select a series twice
            refs = list({ref.sid: ref for ref in refs}.values())
        return _by_entity(refs)

    def _types_taken(self, expr: TypeExpr | None, stored_types: Iterable[str]) -> set[str]:
        """Those of ``stored_types`` whose entities a type expression selects (None: all)."""
        types = list(stored_types)
        if expr is None:
            return set(types)
        iris = self.terms.expand_all(types)
        return {t for t, iri in zip(types, iris, strict=True) if type_matches(expr, partial(_is_type, iri))}

    def attr_iris(self, refs: Sequence[SeriesRef]) -> dict[int, str]:
        """sid → the expanded IRI of its NGSI-LD attribute name (each
        distinct name expanded once: a type's entities share them)."""
        names = {r.sid: r.ld_attr for r in refs}
        distinct = list(set(names.values()))
        iri = dict(zip(distinct, self.terms.expand_all(distinct), strict=True))
        return {sid: iri[name] for sid, name in names.items()}

    def selected(self, query: TemporalQuery, refs: Sequence[SeriesRef], iris: dict[int, str]) -> list[SeriesRef]:
        """The series a response shows: attrs/pick narrowed, omit removed, datasetIds kept."""
        wanted = query.wanted_attrs
        wanted_set = None if wanted is None else set(wanted)
        omit = set(query.omit or ())
        datasets = None if query.dataset_ids is None else set(query.dataset_ids)
        out = []
        for ref in refs:
            iri = iris[ref.sid]
            if wanted_set is not None and iri not in wanted_set:
                continue
            if iri in omit:
                continue
            if datasets is not None and (ref.dataset_id or DEFAULT_DATASET) not in datasets:
                continue
            out.append(ref)
        return out

    # -- 2. q and geo over the window ---------------------------------------------

    def q_matches(
        self, node: qlang.Node, window: Window, by_entity: dict[EntityKey, list[SeriesRef]], iris: dict[int, str]
    ) -> set[EntityKey]:
        """Entities for which ``q`` holds: a term holds when some instance of
        its attribute in the window satisfies it."""
        owner = {r.sid: key for key, refs in by_entity.items() for r in refs}
        sids_of: dict[str, list[int]] = {}
        for sid in owner:
            sids_of.setdefault(iris[sid], []).append(sid)
        holding: dict[qlang.Term, set[EntityKey]] = {}
        for term in dict.fromkeys(qlang.terms(node)):
            sids = sids_of.get(term.attr, [])
            holding[term] = {owner[s] for s in self._term_sids(term, sids, window)} if sids else set()
        return {key for key in by_entity if qlang.evaluate(node, partial(_holds, holding, key))}

    def _term_sids(self, term: qlang.Term, sids: list[int], window: Window) -> set[int]:
        """The series with an instance satisfying ``term``: decided by the
        database when it can (``value_test``), else on the read values."""
        test = value_test(term)
        if test is not None:
            return self.q.instances_matching(sids, instance_window(window), test)
        out = set()
        for sid, kind, num, txt, js, md in self.q.instance_values(sids, instance_window(window)):
            if sid not in out and term.matches(term_value(term, kind, num, txt, js, md)):
                out.add(sid)
        return out

    def geo_matches(
        self, geo, window: Window, by_entity: dict[EntityKey, list[SeriesRef]], iris: dict[int, str]
    ) -> set[EntityKey]:
        """Entities with a location instance in the window that satisfies the geo-query."""
        owner = {r.sid: key for key, refs in by_entity.items() for r in refs if iris[r.sid] == geo.geoproperty}
        return {owner[sid] for sid in self._geo_sids(geo, window, list(owner))}

    def located(self, query: TemporalQuery) -> dict[EntityKey, list[SeriesRef]] | None:
        """A geo-query over whole types (no ids, no idPattern): the series of
        the entities whose location passes it, found from the types'
        location series alone. ``series`` would list every series of every
        entity of the types (100,000 entities: more time than the rest of
        the query) only for all but the few near ones to be dropped. None
        when the query names entities (``series`` then lists few)."""
        geo = query.geo
        if geo is None or query.entity_id is not None:
            return None
        if any(s.ids is not None or s.id_pattern is not None for s in query.selectors):
            return None
        scope = Scope(query.tenant)
        names = self.q.series_names(scope)
        types = set().union(*(self._types_taken(s.types, names) for s in query.selectors))
        ld_names = list({name for t in types for name in names[t]})
        iri = dict(zip(ld_names, self.terms.expand_all(ld_names), strict=True))
        stored = {a for t in types for name, attrs in names[t].items() if iri[name] == geo.geoproperty for a in attrs}
        if not stored:
            return {}
        refs = self.q.series(scope, EntityFilter(types=tuple(sorted(types))), stored)
        sids = list(map(_SID, refs))  # C loops: one per location series of the types
        near = self._geo_sids(geo, query.window, sids)
        keys = {(r.entity_id, r.entity_type) for r in compress(refs, map(near.__contains__, sids))}
        if not keys:
            return {}
        found = self.q.series(scope, EntityFilter(ids=tuple(sorted({k[0] for k in keys}))))
        return _by_entity(r for r in found if (r.entity_id, r.entity_type) in keys)

    def _geo_sids(self, geo, window: Window, sids: list[int]) -> set[int]:
        """Those location series of ``sids`` with an instance in the window that satisfies the geo-query."""
        prefilter = geo.filter.prefilter
        if sids and prefilter is not None:
            # Only those whose locations were ever inside the box (the
            # backends keep each series' extent: memory, or a small table).
            sids = [row[0] for row in self.q.location_extents(sids, prefilter)]
        if not sids:
            return set()
        rows = self.q.location_instances(sids, instance_window(window), prefilter)
        distinct = list({geojson for _, geojson in rows})
        passed = set(compress(distinct, geo.filter.matching(distinct)))
        return {sid for sid, geojson in rows if geojson in passed}


def instance_window(window: Window) -> InstanceWindow:
    """The seam's spelling of a temporal query's window."""
    return InstanceWindow(window.timeproperty.value, window.start, window.end)


def value_test(term: qlang.Term) -> ValueTest | None:
    """The test the database can make for a term on a plain value (no
    sub-property or value path): a numeric comparison, text equality or
    existence. Else None (Python decides on the values)."""
    if term.sub or term.inner:
        return None
    if term.op is None:
        return ValueTest()
    value = term.value
    if term.op not in VALUE_TEST_OPS or isinstance(value, bool):
        return None  # != also holds for non-numbers, lists, ranges, regexes: Python decides
    if isinstance(value, (int, float)):
        return ValueTest(term.op, float(value))
    if isinstance(value, str) and term.op == "==":
        return ValueTest(term.op, value)
    return None


_VALUE_KEYS = ("value", "object", "languageMap", "valueList", "objectList", "vocab", "json")


def term_value(term: qlang.Term, kind, num, txt, js, md):
    """The value a q term looks at in one stored instance: the attribute's
    value, a sub-property's value (``a.b``) or a member inside the value (``a[k]``)."""
    from ..history.service import decode

    if term.sub:
        try:
            node = orjson.loads(md) if md else {}
        except orjson.JSONDecodeError:
            return None
        for step in term.sub:
            if not isinstance(node, dict) or step not in node:
                return None
            node = node[step]
        value = node
        if isinstance(node, dict):
            value = next((node[k] for k in _VALUE_KEYS if k in node), node)
    else:
        value = decode(kind, num, txt, js)
    for step in term.inner:
        if not isinstance(value, dict) or step not in value:
            return None
        value = value[step]
    return value


def _by_entity(refs: Iterable[SeriesRef]) -> dict[EntityKey, list[SeriesRef]]:
    grouped: dict[EntityKey, list[SeriesRef]] = {}
    for ref in refs:
        grouped.setdefault((ref.entity_id, ref.entity_type), []).append(ref)
    return grouped


def _is_type(iri: str, name: TypeName) -> bool:
    """``type_matches``'s test for an entity of type ``iri``."""
    return name.iri == iri


def _holds(holding: dict[qlang.Term, set[EntityKey]], key: EntityKey, term: qlang.Term) -> bool:
    """``qlang.evaluate``'s test: does entity ``key`` satisfy ``term``?"""
    return key in holding[term]
