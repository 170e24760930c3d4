"""An in-memory index of the ``series`` table, for resolving series ids.

Every read starts by turning (tenant, service paths, entities, attributes)
into the series ids to scan. That is a few dictionary look-ups here instead
of a table scan per request. The index is per tenant, so no tenant's lookup
ever touches another's entries.

Series rows are only ever added (deleting samples keeps the series). The
backend's loader returns rows after a position that grows in *commit* order
(series ids do not: several writers allocate them concurrently), so the
index catches up by loading "after the last position seen". Whether it must
is decided by a cheap ``generation()`` counter that grows whenever the
writer publishes new series; it is read *before* loading, so a concurrent
commit can only make the next request reload, never leave the index behind.

Readers never lock: a refresh builds new containers and swaps them in.
"""

from __future__ import annotations

import gc
import threading
from collections.abc import Callable, Iterable, Sequence

from tsdb_service.core import budget
from tsdb_service.core.idpattern import compiled
from tsdb_service.core.query import EntityFilter, Scope, SeriesRef


class _TenantIndex:
    __slots__ = ("all", "by_attr", "by_entity", "by_type", "by_type_attr", "memo", "names")

    def __init__(self) -> None:
        self.all: tuple[SeriesRef, ...] = ()
        self.by_entity: dict[str, tuple[SeriesRef, ...]] = {}
        self.by_type: dict[str, tuple[SeriesRef, ...]] = {}
        self.by_attr: dict[str, tuple[SeriesRef, ...]] = {}
        self.by_type_attr: dict[tuple[str, str], tuple[SeriesRef, ...]] = {}
        # entity type → {NGSI-LD attribute name: the stored names of its series}
        self.names: dict[str, dict[str, tuple[str, ...]]] = {}
        # (types, attrs) → their series by id (``SeriesCatalog.by_sid``); a
        # grown index starts empty, so an entry is never stale
        self.memo: dict[tuple[tuple[str, ...], tuple[str, ...]], dict[int, SeriesRef]] = {}

    def extended(self, refs: Sequence[SeriesRef]) -> _TenantIndex:
        new = _TenantIndex()
        new.all = self.all + tuple(refs)
        new.by_entity = _extend(self.by_entity, refs, lambda r: r.entity_id)
        new.by_type = _extend(self.by_type, refs, lambda r: r.entity_type)
        new.by_attr = _extend(self.by_attr, refs, lambda r: r.attr)
        new.by_type_attr = _extend(self.by_type_attr, refs, lambda r: (r.entity_type, r.attr))
        new.names = self.names
        for ref in refs:
            stored = new.names.get(ref.entity_type, {}).get(ref.ld_attr, ())
            if ref.attr not in stored:
                if new.names is self.names:  # copy on first change: readers hold the old one
                    new.names = {t: dict(attrs) for t, attrs in self.names.items()}
                new.names.setdefault(ref.entity_type, {})[ref.ld_attr] = (*stored, ref.attr)
        return new


def _extend(index: dict, refs: Sequence[SeriesRef], key) -> dict:
    grouped: dict[str, list[SeriesRef]] = {}
    for ref in refs:
        grouped.setdefault(key(ref), []).append(ref)
    out = dict(index)
    for k, more in grouped.items():
        out[k] = out.get(k, ()) + tuple(more)
    return out


# position (commit-ordered), sid, tenant, service path, entity id, entity type, attr[, dataset id]
SeriesRow = tuple

# A load of at least this many series is taken out of the cyclic garbage
# collector's sight (``gc.freeze``). The catalog lives as long as the process,
# yet every full collection walked all of it again: with 100,000 entities
# that was a fifth of the CPU of an NGSI-LD aggregation request.
FREEZE_LOADS_OF = 10_000
MEMO_ENTRIES = 16  # (types, attrs) sets of series kept per tenant index


class SeriesCatalog:
    def __init__(self, load_since: Callable[[int], Iterable[SeriesRow]], generation: Callable[[], object]):
        self._load_since = load_since
        self._generation = generation
        self._lock = threading.Lock()
        self._tenants: dict[str, _TenantIndex] = {}
        self._loaded_gen: object = -1
        self._position = -1
        self._known: set[int] = set()
        self._refs: dict[int, SeriesRef] = {}  # every loaded series by id (swapped, never mutated)

    def refresh(self) -> None:
        if self._generation() == self._loaded_gen:
            return
        with self._lock:
            gen = self._generation()
            if gen == self._loaded_gen:
                return
            rows = list(self._load_since(self._position))
            by_tenant: dict[str, list[SeriesRef]] = {}
            position = self._position
            by_sid = dict(self._refs)
            for pos, sid, tenant, path, eid, etype, attr, *dataset in rows:
                position = max(position, pos)
                if sid in self._known:
                    continue
                self._known.add(sid)
                ref = by_sid[sid] = SeriesRef(sid, path, eid, etype, attr, dataset[0] if dataset else None)
                by_tenant.setdefault(tenant, []).append(ref)
            tenants = dict(self._tenants)
            for tenant, refs in by_tenant.items():
                tenants[tenant] = tenants.get(tenant, _EMPTY).extended(refs)
            self._tenants = tenants
            self._refs = by_sid
            self._position = position
            self._loaded_gen = gen
        if len(rows) >= FREEZE_LOADS_OF:
            _freeze()

    def refs(self, sids) -> dict[int, SeriesRef]:
        """The series with these ids (those loaded; call after ``select``)."""
        refs = self._refs
        return {sid: refs[sid] for sid in sids if sid in refs}

    def tenants(self) -> list[str]:
        """Every tenant that has at least one series, sorted."""
        self.refresh()
        return sorted(self._tenants)

    def names(self, tenant: str) -> dict[str, dict[str, tuple[str, ...]]]:
        """Entity type → {NGSI-LD attribute name: stored names (``attr`` and
        ``attr~datasetId``)} of a tenant: what a type-wide query selects
        through ``by_type_attr`` instead of listing every series."""
        self.refresh()
        index = self._tenants.get(tenant)
        return {} if index is None else index.names

    def by_sid(self, tenant: str, types: Iterable[str], attrs: Iterable[str]) -> dict[int, SeriesRef]:
        """Every series of ``tenant`` of an entity of ``types`` with a stored
        name in ``attrs``, by id. Kept until the tenant's index next grows:
        a type-wide geo-query tests each candidate's id against it, and
        would otherwise build it from 100,000 series at each request. Do
        not change the dict returned."""
        self.refresh()
        index = self._tenants.get(tenant)
        if index is None:
            return {}
        key = (tuple(sorted(set(types))), tuple(sorted(set(attrs))))
        found = index.memo.get(key)
        if found is None:
            found = {r.sid: r for t in key[0] for a in key[1] for r in index.by_type_attr.get((t, a), ())}
            if len(index.memo) >= MEMO_ENTRIES:
                index.memo.clear()
            index.memo[key] = found
        budget.check_series(len(found))
        return found

    def select(
        self,
        scope: Scope,
        entities: EntityFilter,
        attrs: Iterable[str] | None = None,
    ) -> list[SeriesRef]:
        """The series of ``scope`` matching ``entities`` and attribute names."""
        self.refresh()
        index = self._tenants.get(scope.tenant)
        if index is None:
            return []
        attr_set = None if attrs is None else set(attrs)
        if (
            entities.ids is None
            and entities.id_pattern is None
            and entities.types is not None
            and attr_set is not None
            and scope.whole_tenant
        ):
            # "attribute A of every entity of type T": the common dashboard and
            # geo question, answered by one index look-up per (T, A).
            found = [r for t in entities.types for a in attr_set for r in index.by_type_attr.get((t, a), ())]
            budget.check_series(len(found))
            return found
        if entities.ids is not None:
            candidates: Iterable[SeriesRef] = [r for eid in entities.ids for r in index.by_entity.get(eid, ())]
        elif attr_set is not None and len(attr_set) <= 4:
            candidates = [r for a in attr_set for r in index.by_attr.get(a, ())]
            if entities.types is not None:
                wanted_types = set(entities.types)
                candidates = [r for r in candidates if r.entity_type in wanted_types]
        elif entities.types is not None:
            candidates = [r for t in entities.types for r in index.by_type.get(t, ())]
        else:
            candidates = index.all
        types: set[str] | None = set(entities.types) if entities.types is not None else None
        pattern = compiled(entities.id_pattern) if entities.id_pattern else None
        whole = scope.whole_tenant
        out = []
        for ref in candidates:
            if types is not None and ref.entity_type not in types:
                continue
            if attr_set is not None and ref.attr not in attr_set:
                continue
            if not whole and not scope.matches(ref.service_path):
                continue
            if pattern is not None and pattern.search(ref.entity_id) is None:
                continue
            out.append(ref)
        budget.check_series(len(out))  # the request's series budget (tsdb_service.core.budget)
        return out


_EMPTY = _TenantIndex()


def _freeze() -> None:
    """Move every object alive now to the collector's permanent generation
    (after a collection, so no garbage is kept): it is never scanned again."""
    gc.collect()
    gc.freeze()
