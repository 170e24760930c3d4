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
   in the window, taken together in one ``Querier.window_scan``: a
   comparison on numbers or text is decided by the database, and a
   geo-query reads the locations whose stored box passes its prefilter
   and applies the exact, geodesic predicate in Python. Any other ``q``
   term reads the candidate values (``Querier.instance_values``) of the
   entities the geo-query left.
3. The matching entities are sorted by id (then type) and paged.
4. Only the page's series are read (``ngsild.service``): instances in the
   window through ``Querier.temporal_instances`` (``lastN`` per series, at
   most ``cap + 1`` so a cut is detected: 206), or one grouped aggregation
   statement (``ngsild.aggregate``, ``Querier.instance_aggregate``). The
   SQL of each is rendered in storage (``storage.sql.temporal``).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from functools import partial
from itertools import compress

import orjson

from tsdb_service.core.model import Kind
from tsdb_service.core.query import (
    ARRAY_INSTANCE,
    VALUE_TEST_OPS,
    EntityFilter,
    InstanceWindow,
    Scope,
    SeriesRef,
    ValueTest,
)
from tsdb_service.faces.ngsild import qlang
from tsdb_service.faces.ngsild.context import TermMap
from tsdb_service.faces.ngsild.query import (
    DEFAULT_DATASET,
    TemporalQuery,
    TypeAnd,
    TypeExpr,
    TypeName,
    TypeOr,
    Window,
    type_matches,
)
from tsdb_service.read import TemporalReads
from tsdb_service.read.requests import ExtentsNear, InstancesIn, LocatedSelect, SeriesSelect, WindowScan

EntityKey = tuple[str, str]  # (entity id, stored entity type)


class Fetcher:
    """Answers one query's questions through the read seam (``read.Querier``)."""

    def __init__(self, querier: TemporalReads, terms: TermMap):
        self.q = querier
        self.terms = terms
        self.types: dict[str, tuple[str, ...]] = {}  # entity id → its stored types, sorted

    # -- 1. series ---------------------------------------------------------------

    def series(self, query: TemporalQuery) -> dict[EntityKey, list[SeriesRef]]:
        """Every selected series, grouped by entity; attributes and datasetIds
        narrowed, entities kept even when none of their attributes is selected
        (they still match; their attributes are empty). An entity is its id:
        its types are every type it was stored under (clause 4.16), which a
        type expression is judged on, and all its series are its own."""
        scope = Scope(query.tenant)
        refs: list[SeriesRef] = []
        for selector in query.selectors:
            ids = (query.entity_id,) if query.entity_id is not None else selector.ids
            found = self.q.series(SeriesSelect(scope, EntityFilter(ids=ids, id_pattern=selector.id_pattern)))
            if selector.types is not None:
                found = self._of_types(selector.types, found)
            refs.extend(found)
        if len(query.selectors) > 1:  # alternatives may select a series twice
            refs = list({ref.sid: ref for ref in refs}.values())
        return self._by_entity(refs)

    def _of_types(self, expr: TypeExpr, refs: list[SeriesRef]) -> list[SeriesRef]:
        """The series of the entities whose types (all their stored types)
        satisfy ``expr``."""
        stored = sorted({r.entity_type for r in refs})
        iri = dict(zip(stored, self.terms.expand_all(stored), strict=True))
        types_of: dict[str, set[str]] = {}
        for ref in refs:
            types_of.setdefault(ref.entity_id, set()).add(iri[ref.entity_type])
        ok = {eid for eid, iris in types_of.items() if type_matches(expr, partial(_has_type, iris))}
        return [r for r in refs if r.entity_id in ok]

    def _by_entity(self, refs: Iterable[SeriesRef]) -> dict[EntityKey, list[SeriesRef]]:
        """Series grouped by entity id, keyed (id, its first stored type); the
        entity's types kept in ``types``."""
        by_id: dict[str, list[SeriesRef]] = {}
        for ref in refs:
            by_id.setdefault(ref.entity_id, []).append(ref)
        out: dict[EntityKey, list[SeriesRef]] = {}
        for eid, group in by_id.items():
            types = tuple(sorted({r.entity_type for r in group}))
            self.types[eid] = types
            out[(eid, types[0])] = group
        return out

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

    def matching(
        self,
        query: TemporalQuery,
        by_entity: dict[EntityKey, list[SeriesRef]],
        iris: dict[int, str],
        located: Sequence[int] | None = None,
        alive: tuple[Sequence[int], ValueTest] | None = None,
    ) -> set[EntityKey]:
        """The entities of ``by_entity`` for which the geo-query and ``q``
        hold, each judged on the instances in the window (a ``q`` term holds
        when some instance of its attribute satisfies it), and, given
        ``alive`` (series, test), which have an instance of one of those
        series in the window that passes the test (asked with ``q``'s reads).

        What the database can decide is asked through ``Querier.
        window_scan``: the location instances whose stored box passes the
        geo-query's prefilter, and per ``q`` term on a plain value
        (``value_test``) the series with an instance passing it. Where each
        read scans the samples (``Querier.shared_scan``, DuckDB) they are
        asked together; else ``q`` is asked after the geo-query, of the
        entities it left. The exact, geodesic geo test is made here, and the
        other ``q`` terms on the values of the entities the geo-query left.
        ``located``: the location series already past the extents' test
        (``located``)."""
        window = instance_window(query.window)
        owner = {r.sid: key for key, refs in by_entity.items() for r in refs}
        keys = set(by_entity)
        geo = query.geo
        locations = None
        if geo is not None:
            if located is None:
                located = self._ever_near(geo, [sid for sid in owner if iris[sid] == geo.geoproperty])
            locations = ([sid for sid in located if sid in owner], geo.filter.prefilter)
            if not locations[0]:
                return set()
            if query.q is None or not self.q.shared_scan:
                rows, _ = self.q.window_scan(WindowScan(window, locations, []))
                keys = {owner[sid] for sid in self._passing(geo, rows)}
                locations = None
        if (query.q is None and alive is None) or not keys:
            return keys
        terms = list(dict.fromkeys(qlang.terms(query.q))) if query.q is not None else []
        sids_of: dict[str, list[int]] = {}
        for sid, key in owner.items():
            if key in keys:
                sids_of.setdefault(iris[sid], []).append(sid)
        tested = [(term, test) for term in terms if (test := value_test(term)) is not None]
        probes = [(sids_of.get(t.attr, []), test) for t, test in tested]
        # An array instance matches a term when one of its elements does,
        # which the database's test on plain values cannot see: the series
        # with array instances are asked for too, and tested here.
        compared = [t for t, test in tested if test.op is not None]
        arrays = list({sid for t in compared for sid in sids_of.get(t.attr, [])})
        if arrays:
            probes.append((arrays, ValueTest(ARRAY_INSTANCE)))
        if alive is not None:
            probes.append(([sid for sid in alive[0] if owner.get(sid) in keys], alive[1]))
        rows, found = self.q.window_scan(WindowScan(window, locations, probes))
        if alive is not None:
            keys &= {owner[sid] for sid in found[-1]}
            found = found[:-1]
        with_arrays = found.pop() if arrays else set()
        if locations is not None:
            keys &= {owner[sid] for sid in self._passing(geo, rows)}
        if query.q is None or not keys:
            return keys
        holding = {term: {owner[sid] for sid in sids} for (term, _), sids in zip(tested, found, strict=True)}
        for term in compared:
            passed = holding[term]
            among = [sid for sid in sids_of.get(term.attr, []) if sid in with_arrays and owner[sid] not in passed]
            holding[term] |= {owner[sid] for sid in self._values_passing(term, among, window)}
        for term in terms:
            if term not in holding:
                sids = [sid for sid in sids_of.get(term.attr, []) if owner[sid] in keys]
                holding[term] = {owner[sid] for sid in self._values_passing(term, sids, window)}
        return {key for key in keys if qlang.evaluate(query.q, partial(_holds, holding, key))}

    def _values_passing(self, term: qlang.Term, sids: list[int], window: InstanceWindow) -> set[int]:
        """Those of ``sids`` with an instance satisfying ``term``, tested on
        the read values (a term the database cannot decide)."""
        out: set[int] = set()
        if not sids:
            return out
        ordering = term.op in qlang.ORDERING
        for sid, kind, num, txt, js, md in self.q.instance_values(InstancesIn(sids, window)):
            if sid in out or (ordering and is_relationship(term, kind, md)):
                continue  # an ordering operator never matches a Relationship (clause 4.9)
            if term.matches(term_value(term, kind, num, txt, js, md)):
                out.add(sid)
        return out

    def located(self, query: TemporalQuery) -> tuple[dict[EntityKey, list[SeriesRef]], list[int]] | None:
        """A geo-query over whole types (no ids, no idPattern): the entities
        whose location may pass it, found from the types' location series
        alone, with their series, and those location series. ``series``
        would list every series of every entity of the types (100,000
        entities: more time than the rest of the query) only for all but
        the few near ones to be dropped. None when the query names entities
        (``series`` then lists few)."""
        geo = query.geo
        if geo is None or query.entity_id is not None:
            return None
        if any(s.ids is not None or s.id_pattern is not None for s in query.selectors):
            return None
        if any(s.types is not None and any(isinstance(n, TypeAnd) for n in _nodes(s.types)) for s in query.selectors):
            return None  # an entity's types together decide an AND: ``series`` judges them
        scope = Scope(query.tenant)
        names = self.q.series_names(scope)
        types = set().union(*(self._types_taken(s.types, names) for s in query.selectors))
        ld_names = list({name for t in types for name in names[t]})
        iri = dict(zip(ld_names, self.terms.expand_all(ld_names), strict=True))
        stored = {a for t in types for name, attrs in names[t].items() if iri[name] == geo.geoproperty for a in attrs}
        if not stored:
            return {}, []
        near = self.q.located_series(LocatedSelect(scope, sorted(types), stored, geo.filter.prefilter))
        keys = {(r.entity_id, r.entity_type) for r in near}
        if not keys:
            return {}, []
        found = self.q.series(SeriesSelect(scope, EntityFilter(ids=tuple(sorted({k[0] for k in keys})))))
        return self._by_entity(found), [r.sid for r in near]

    def _ever_near(self, geo, sids: list[int]) -> list[int]:
        """Those location series of ``sids`` whose stored extent passes the
        geo-query's prefilter (the backends keep each series' extent:
        memory, or a small table), so only their instances are read."""
        prefilter = geo.filter.prefilter
        if sids and prefilter is not None:
            return [row[0] for row in self.q.location_extents(ExtentsNear(sids, prefilter))]
        return sids

    @staticmethod
    def _passing(geo, rows: list[tuple[int, str]]) -> set[int]:
        """The series of ``rows`` (sid, GeoJSON) with a location that
        satisfies the geo-query: each distinct GeoJSON tested once, in one
        array call."""
        distinct = list({geojson for _, geojson in rows})
        passed = set(compress(distinct, geo.filter.matching(distinct)))
        return {sid for sid, geojson in rows if geojson in passed}


def instance_window(window: Window) -> InstanceWindow:
    """The seam's spelling of a temporal query's window."""
    return InstanceWindow(window.timeproperty.value, window.start, window.end, window.spans)


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
    from tsdb_service.history.service import decode

    if term.sub:
        node = _sub_attribute(term, md)
        value = next((node[k] for k in _VALUE_KEYS if k in node), node) if isinstance(node, dict) else node
    else:
        value = decode(kind, num, txt, js)
    return _inside(value, term.inner)


def _sub_attribute(term: qlang.Term, md: str | None):
    """The sub-attribute ``term.sub`` names in an instance's other members
    (``md``, JSON text), or None."""
    try:
        node = orjson.loads(md) if md else {}
    except orjson.JSONDecodeError:
        return None
    for step in term.sub:
        if not isinstance(node, dict) or step not in node:
            return None
        node = node[step]
    return node


def _inside(value, steps: tuple[str, ...]):
    """The member at ``steps`` inside ``value`` (None when missing); ``*``
    is every member of an object or element of an array, as a list (which
    ``Term.matches`` reads element by element)."""
    for i, step in enumerate(steps):
        if step == "*":
            items = list(value.values()) if isinstance(value, dict) else value if isinstance(value, list) else None
            if items is None:
                return None
            found = [_inside(item, steps[i + 1 :]) for item in items]
            return [item for item in found if item is not None]
        if not isinstance(value, dict) or step not in value:
            return None
        value = value[step]
    return value


def is_relationship(term: qlang.Term, kind: int, md: str | None) -> bool:
    """Is the value ``term`` looks at a Relationship's object (the
    attribute itself, or the sub-attribute ``term.sub`` names)?"""
    if not term.sub:
        return kind == int(Kind.RELATIONSHIP) and not term.inner
    node = _sub_attribute(term, md)
    return isinstance(node, dict) and ("object" in node or node.get("type") == "Relationship")


def _is_type(iri: str, name: TypeName) -> bool:
    """``type_matches``'s test for an entity of type ``iri``."""
    return name.iri == iri


def _has_type(iris: set[str], name: TypeName) -> bool:
    """``type_matches``'s test for an entity of the types ``iris``."""
    return name.iri in iris


def _nodes(expr) -> list:
    """Every node of a type expression."""
    if isinstance(expr, (TypeAnd, TypeOr)):
        return [expr, *(n for part in expr.parts for n in _nodes(part))]
    return [expr]


def _holds(holding: dict[qlang.Term, set[EntityKey]], key: EntityKey, term: qlang.Term) -> bool:
    """``qlang.evaluate``'s test: does entity ``key`` satisfy ``term``?"""
    return key in holding[term]
