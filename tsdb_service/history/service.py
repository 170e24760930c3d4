"""Answering history queries: series resolution, sample reads, result rows.

The flow for every read is the same: resolve the request's series ids on the
catalog (no sample is touched), read samples by those ids through the
``Querier``, then build per-entity results that ``faces.quantumleap.shape`` renders.
Everything here is backend-neutral.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import orjson

from tsdb_service.core import budget
from tsdb_service.core.errors import AggrNotApplicable, Conflict, NotFound
from tsdb_service.core.model import Kind
from tsdb_service.core.query import (
    AggBranch,
    AggrMethod,
    AggrScope,
    DeleteQuery,
    EntityFilter,
    EntityListQuery,
    HistoryQuery,
    LastValueQuery,
    Scope,
    SeriesRef,
    Shape,
    TimeRange,
    ValuePath,
)
from tsdb_service.geo.filter import GeoFilter
from tsdb_service.history.valuepath import extract
from tsdb_service.read import HistoryReads
from tsdb_service.read.requests import AggregateRead, RowsRead, SamplesIn, SeriesSelect, ValuesAt

_SINGLE_ENTITY = (Shape.ENTITY_ATTR, Shape.ENTITY)


def not_found() -> NotFound:
    return NotFound("No records were found for such query.", error="Not Found")


@dataclass(slots=True)
class EntityResult:
    """One entity's (or, for aggrScope=global, one group's) history."""

    entity_type: str
    entity_id: str
    index: list = field(default_factory=list)
    columns: dict[str, list] = field(default_factory=dict)  # attrName -> values
    ids: list[str] | None = None  # global scope: the entities aggregated
    types: list[str] | None = None
    # global scope: per column, the (ids, types) that contributed to it
    column_members: dict[str, tuple[list[str], list[str]]] | None = None


@dataclass(slots=True)
class HistoryResult:
    query: HistoryQuery
    entities: list[EntityResult]  # ordered for the response


# --- decoding stored values ------------------------------------------------------

_NUMBER, _INTEGER, _BOOLEAN = int(Kind.NUMBER), int(Kind.INTEGER), int(Kind.BOOLEAN)
_TEXTUAL = frozenset({int(Kind.TEXT), int(Kind.DATETIME), int(Kind.RELATIONSHIP)})
_JSON = frozenset({int(Kind.STRUCTURED), int(Kind.GEO)})


def decode(kind: int, num, txt, js):
    """A stored sample back to its JSON value."""
    if kind == _NUMBER:
        return num
    if kind == _INTEGER:
        return int(num) if num is not None else None
    if kind in _TEXTUAL:
        return txt
    if kind in _JSON:
        return orjson.loads(js) if js is not None else None
    if kind == _BOOLEAN:
        if num is not None:
            return bool(num)
        return orjson.loads(js) if js is not None else None
    return None


# --- series resolution -------------------------------------------------------------


def _attr_names(attrs: Sequence[ValuePath] | None) -> set[str] | None:
    return None if attrs is None else {vp.attr for vp in attrs}


def resolve_entity_series(
    querier: HistoryReads, scope: Scope, entities: EntityFilter, attrs: set[str] | None
) -> list[SeriesRef]:
    """Series of one entity id; without a type, the id must name one type."""
    if entities.types is not None and len(entities.types) == 1:
        return querier.series(SeriesSelect(scope, entities, attrs))
    # Which types does this id have (any attribute)? A series lookup only.
    everything = querier.series(SeriesSelect(scope, entities))
    refs = everything if attrs is None else [r for r in everything if r.attr in attrs]
    types = {r.entity_type for r in everything}
    if len(types) > 1:
        # Deleted data leaves series rows behind: count only types with samples.
        alive = querier.sids_with_samples([r.sid for r in everything])
        types = {r.entity_type for r in everything if r.sid in alive}
        if len(types) > 1:
            eid = entities.ids[0] if entities.ids else ""
            raise Conflict(
                f"entity id {eid!r} exists in several types ({', '.join(sorted(types))}): give 'type' to choose one",
                error="AmbiguousNGSIIdError",
            )
        refs = [r for r in refs if r.entity_type in types]
    return refs


# --- history -------------------------------------------------------------------------


def _geo_refs(
    querier: HistoryReads, scope: Scope, entities: EntityFilter, refs: list[SeriesRef], geo: GeoFilter, time: TimeRange
) -> tuple[list[SeriesRef], HistoryReads]:
    """``(refs, querier)``: the series of entities with matching locations,
    and a querier that reads only matching samples (see history.geo_matching)."""
    from tsdb_service.history.geo_matching import apply_geo

    if entities.ids is not None and len({r.entity_type for r in refs}) == 1:
        # A single-entity request resolved its type already: match within it.
        entities = EntityFilter(ids=entities.ids, id_pattern=entities.id_pattern, types=(refs[0].entity_type,))
    return apply_geo(querier, scope, entities, refs, geo, time)


def run_history(querier: HistoryReads, q: HistoryQuery) -> HistoryResult:
    names = _attr_names(q.attrs)
    if q.shape in _SINGLE_ENTITY:
        refs = resolve_entity_series(querier, q.scope, q.entities, names)
    else:
        refs = querier.series(SeriesSelect(q.scope, q.entities, names))
    if refs and q.geo is not None:
        refs, querier = _geo_refs(querier, q.scope, q.entities, refs, q.geo, q.time)
    if not refs:
        return HistoryResult(q, [])
    answer = _raw if q.aggregation is None else _aggregated
    entities = [ent for group in _type_windows(q, refs) for ent in answer(querier, q, group)]
    return HistoryResult(q, _order(q, entities))


def type_key(entity_type: str) -> tuple[str, str]:
    """Types in QuantumLeap's order: it answers type after type, by table
    name, and a table is named after the lower-cased type."""
    return entity_type.lower(), entity_type


def _type_windows(q: HistoryQuery, refs: list[SeriesRef]) -> list[list[SeriesRef]]:
    """The series answered together. QuantumLeap reads each type from its own
    table, so ``lastN``, ``limit`` and ``offset`` apply per type: the last
    sample of every listed entity of another type is not pushed out by this
    type's newer ones. A global aggregate is one group across types."""
    if q.aggregation is not None and q.aggregation.scope is AggrScope.GLOBAL:
        return [refs]
    by_type: dict[str, list[SeriesRef]] = {}
    for ref in refs:
        by_type.setdefault(ref.entity_type, []).append(ref)
    if len(by_type) == 1:
        return [refs]
    return [by_type[t] for t in sorted(by_type, key=type_key)]


def _columns_by_attr(q: HistoryQuery) -> dict[str, list[tuple[str, tuple]]] | None:
    """attr -> [(column name, steps)]; None means every attribute as itself."""
    if q.attrs is None:
        return None
    out: dict[str, list[tuple[str, tuple]]] = {}
    for vp in q.attrs:
        out.setdefault(vp.attr, []).append((vp.text, vp.steps))
    return out


def _raw(querier: HistoryReads, q: HistoryQuery, refs: list[SeriesRef]) -> list[EntityResult]:
    by_sid = {r.sid: r for r in refs}
    attr_count = len({r.attr for r in refs})
    n = min(q.last_n, q.limit) if q.last_n else q.limit
    rows = querier.raw_rows(
        RowsRead(
            list(by_sid),
            q.time,
            newest_first=q.last_n is not None,
            limit=budget.row_cap(n),
            offset=q.offset,
            one_per_row=attr_count == 1,
            attrs_per_row=attr_count,
        )
    )
    budget.charge_rows(len(rows))  # past the request's budget: 422 (tsdb_service.core.budget)
    if not rows:
        return []
    wanted = _columns_by_attr(q)
    if len(by_sid) == 1 and (wanted is None or len(wanted[refs[0].attr]) == 1):
        return [_one_series(refs[0], rows, wanted)]
    if attr_count == 1 and (wanted is None or _plain_single(wanted)):
        return _one_attribute(by_sid, rows, wanted)
    plain = [(None, ())]
    results: dict[tuple[str, str], EntityResult] = {}
    last_rid: dict[tuple[str, str], int] = {}
    for sid, rid, iso, kind, num, txt, js in rows:
        ref = by_sid[sid]
        key = (ref.entity_type, ref.entity_id)
        ent = results.get(key)
        if ent is None:
            ent = results[key] = EntityResult(ref.entity_type, ref.entity_id)
            last_rid[key] = -1
        if last_rid[key] != rid:
            last_rid[key] = rid
            ent.index.append(iso)
        row = len(ent.index) - 1
        value = decode(kind, num, txt, js)
        targets = plain if wanted is None else wanted.get(ref.attr, ())
        for name, steps in targets:
            column = ent.columns.get(name or ref.attr)
            if column is None:
                column = ent.columns[name or ref.attr] = []
            if len(column) < row:
                column.extend([None] * (row - len(column)))
            column.append(extract(value, steps) if steps else value)
    for ent in results.values():
        size = len(ent.index)
        for column in ent.columns.values():
            if len(column) < size:
                column.extend([None] * (size - len(column)))
    return list(results.values())


def _plain_single(wanted: dict[str, list[tuple[str, tuple]]]) -> bool:
    """Each attribute asked once, as itself (no value path)."""
    return all(len(columns) == 1 and not columns[0][1] for columns in wanted.values())


def _one_attribute(by_sid: dict[int, SeriesRef], rows: list[tuple], wanted) -> list[EntityResult]:
    """One attribute over many entities (``/v2/types/T/attrs/A``): every
    sample is a row of its entity, so no row grouping by ``rid`` is needed;
    this loop is the whole per-row cost of a type-level lastN."""
    results: dict[tuple[str, str], EntityResult] = {}
    targets: dict[int, tuple[list, list]] = {}
    number = _NUMBER
    for sid, _rid, iso, kind, num, txt, js in rows:
        target = targets.get(sid)
        if target is None:
            ref = by_sid[sid]
            key = (ref.entity_type, ref.entity_id)
            ent = results.get(key)
            if ent is None:
                ent = results[key] = EntityResult(ref.entity_type, ref.entity_id)
            name = ref.attr if wanted is None else wanted[ref.attr][0][0]
            target = targets[sid] = (ent.index, ent.columns.setdefault(name, []))
        target[0].append(iso)
        target[1].append(num if kind == number else decode(kind, num, txt, js))
    return list(results.values())


def _one_series(ref: SeriesRef, rows: list[tuple], wanted) -> EntityResult:
    """The common case, one series: every sample is a row of its own."""
    name, steps = (ref.attr, ()) if wanted is None else wanted[ref.attr][0]
    if all(row[3] == _NUMBER for row in rows):
        values = [row[4] for row in rows]
    else:
        values = [decode(kind, num, txt, js) for _s, _r, _t, kind, num, txt, js in rows]
    if steps:
        values = [extract(v, steps) for v in values]
    ent = EntityResult(ref.entity_type, ref.entity_id, [row[2] for row in rows])
    ent.columns[name] = values
    return ent


_GLOBAL = ("", "")


def _aggregated(querier: HistoryReads, q: HistoryQuery, refs: list[SeriesRef]) -> list[EntityResult]:
    agg = q.aggregation
    assert agg is not None, "run_history sends only aggregated queries here"
    method = agg.method
    by_sid = {r.sid: r for r in refs}
    # Columns: plain attributes share one branch; each value path has its own.
    plain_attrs: dict[str, str] = {}  # attr -> column name
    path_columns: list[ValuePath] = []
    explicit = q.attrs is not None
    if q.attrs is not None:
        for vp in q.attrs:
            if vp.steps:
                path_columns.append(vp)
            else:
                plain_attrs[vp.attr] = vp.text
    else:
        for r in refs:
            plain_attrs[r.attr] = r.attr
    branches = [AggBranch(tuple(r.sid for r in refs if r.attr in plain_attrs))]
    for vp in path_columns:
        branches.append(AggBranch(tuple(r.sid for r in refs if r.attr == vp.attr), vp.steps))
    rows = querier.aggregate(AggregateRead(branches, q.time, agg))
    budget.charge_rows(len(rows))
    global_scope = agg.scope is AggrScope.GLOBAL
    cells, totals, members = _cells(rows, by_sid, plain_attrs, path_columns, method, global_scope)

    if method is not AggrMethod.COUNT:
        for present, numeric in totals.values():
            if explicit and present and not numeric:
                raise AggrNotApplicable()
        if not explicit:  # every attribute: the non-numeric ones are left out
            cells = {k: v for k, v in cells.items() if totals[k[1]][1] > 0}

    group_buckets: dict[tuple, set] = {}
    group_columns: dict[tuple, list[str]] = {}
    for group, column in cells:
        group_buckets.setdefault(group, set()).update(cells[(group, column)])
        group_columns.setdefault(group, []).append(column)
    # QuantumLeap's windowing of aggregated rows: ordered by entity, then
    # period (newest first for lastN); offset and limit apply to those rows
    # (of one type: run_history calls this type after type).
    newest_first = q.last_n is not None
    skip = q.offset
    room = min(q.last_n, q.limit) if q.last_n else q.limit
    out = []
    for group in sorted(group_buckets):
        if room <= 0:
            break
        buckets = group_buckets[group]
        if skip >= len(buckets):
            skip -= len(buckets)
            continue
        # With a period every bucket is an ISO text (sorts as itself); without, there is one (None).
        ordered = sorted(buckets, reverse=newest_first) if len(buckets) > 1 else list(buckets)
        taken = ordered[skip : skip + room]
        skip, room = 0, room - len(taken)
        kept = taken[::-1] if newest_first else taken  # oldest first
        ent = EntityResult(group[0], group[1])
        if agg.period is not None:
            ent.index = kept
        for column in sorted(group_columns[group]):
            ent.columns[column] = _finals(method, cells[(group, column)], kept)
        if global_scope:
            ent.ids = sorted({eid for _t, eid in members.get(group, ())})
            ent.types = sorted({t for t, _eid in members.get(group, ())})
            ent.column_members = {
                column: (
                    sorted({eid for _t, eid in members.get((group, column), ())}),
                    sorted({t for t, _eid in members.get((group, column), ())}),
                )
                for column in ent.columns
            }
        out.append(ent)
    return out


def _cells(rows, by_sid, plain_attrs, path_columns, method, global_scope):
    """The aggregate rows combined per (group, column) and bucket:
    ``({(group, column): {bucket: [n_present, n_numeric, value, all_integer]}},
    {column: [present, numeric]}, members)``. A series' rows usually come
    together: its group and column are looked up once per run of them."""
    cells: dict[tuple, dict] = {}
    members: dict[tuple, set] = {}
    totals: dict[str, list[int]] = {}
    last_branch = last_sid = None
    by_bucket: dict = {}
    total = [0, 0]
    for branch, sid, bucket, n_present, n_numeric, value, all_int in rows:
        if sid != last_sid or branch != last_branch:
            last_branch, last_sid = branch, sid
            ref = by_sid[sid]
            column = plain_attrs[ref.attr] if branch == 0 else path_columns[branch - 1].text
            group = _GLOBAL if global_scope else (ref.entity_type, ref.entity_id)
            if global_scope:
                members.setdefault(group, set()).add((ref.entity_type, ref.entity_id))
                members.setdefault((group, column), set()).add((ref.entity_type, ref.entity_id))
            total = totals.setdefault(column, [0, 0])
            by_bucket = cells.setdefault((group, column), {})
        total[0] += n_present
        total[1] += n_numeric
        cell = by_bucket.get(bucket)
        if cell is None:
            by_bucket[bucket] = [n_present, n_numeric, value, all_int]
        else:
            cell[0] += n_present
            cell[1] += n_numeric
            cell[2] = _combine(method, cell[2], value)
            cell[3] = _and(cell[3], all_int)
    return cells, totals, members


def _finals(method: AggrMethod, by_bucket: dict, buckets: list) -> list:
    """``_final`` of each bucket's cell; the average inline (the common case)."""
    if method is AggrMethod.AVG:
        return [None if c is None or not c[1] or c[2] is None else c[2] / c[1] for c in map(by_bucket.get, buckets)]
    return [_final(method, by_bucket.get(b)) for b in buckets]


def _combine(method: AggrMethod, a, b):
    if a is None:
        return b
    if b is None:
        return a
    if method is AggrMethod.MIN:
        return min(a, b)
    if method is AggrMethod.MAX:
        return max(a, b)
    return a + b  # sum, and avg's running sum


def _and(a, b):
    if a is None:
        return b
    if b is None:
        return a
    return a and b


def _final(method: AggrMethod, cell):
    if cell is None:
        return None
    present, numeric, value, all_int = cell
    if method is AggrMethod.COUNT:
        return present
    if not numeric or value is None:
        return None
    if method is AggrMethod.AVG:
        return value / numeric
    if all_int and float(value).is_integer():
        return int(value)
    return float(value)


def _order(q: HistoryQuery, entities: list[EntityResult]) -> list[EntityResult]:
    """Type after type (``type_key``), ascending ids within a type; on
    /v2/types/{type}/attrs/{attr} the ids given in ``id`` come first, in the
    order given. All as in QuantumLeap."""
    entities.sort(key=lambda e: (type_key(e.entity_type), e.entity_id))
    if (
        q.shape is Shape.TYPE_ATTR
        and q.entities.ids
        and (q.aggregation is None or q.aggregation.scope is AggrScope.ENTITY)
    ):
        rank = {eid: i for i, eid in enumerate(q.entities.ids)}
        entities.sort(key=lambda e: (rank.get(e.entity_id, len(rank)), e.entity_id))
    return entities


# --- entity list -------------------------------------------------------------------------


def run_entity_list(querier: HistoryReads, q: EntityListQuery) -> list[dict]:
    refs = querier.series(SeriesSelect(q.scope, q.entities))
    if refs and q.geo is not None:
        refs, querier = _geo_refs(querier, q.scope, q.entities, refs, q.geo, q.time)
    if not refs:
        return []
    by_sid = {r.sid: r for r in refs}
    latest: dict[tuple[str, str], str] = {}
    for sid, iso in querier.latest_index(SamplesIn(list(by_sid), q.time)):
        ref = by_sid[sid]
        key = (ref.entity_type, ref.entity_id)
        if iso > latest.get(key, ""):
            latest[key] = iso
    # QuantumLeap pages newest first (then type, id) and lists each page by id.
    items = sorted(latest.items(), key=lambda kv: (kv[0][0], kv[0][1]))
    items.sort(key=lambda kv: kv[1], reverse=True)
    page = sorted(items[q.offset : q.offset + q.limit], key=lambda kv: (kv[0][1], kv[0][0]))
    return [{"id": eid, "type": etype, "index": iso} for (etype, eid), iso in page]


# --- last values (op/query) -----------------------------------------------------------------


def json_type_name(value) -> str:
    if isinstance(value, bool):
        return "Boolean"
    if isinstance(value, (int, float)):
        return "Number"
    if isinstance(value, str):
        return "Text"
    if value is None:
        return "None"
    return "StructuredValue"


def run_last_values(querier: HistoryReads, q: LastValueQuery) -> list[dict]:
    names = _attr_names(q.attrs)
    refs: dict[int, SeriesRef] = {}
    for selector in q.selectors:
        for ref in querier.series(SeriesSelect(q.scope, selector, names)):
            refs[ref.sid] = ref
    if not refs:
        return []
    wanted: dict[str, list[ValuePath]] | None = None
    if q.attrs is not None:
        wanted = {}
        for vp in q.attrs:
            wanted.setdefault(vp.attr, []).append(vp)
    entities: dict[tuple[str, str], dict] = {}
    modified: dict[tuple[str, str], str] = {}
    sids = list(refs)
    rows = querier.last_values(sids) if q.as_of is None else querier.values_at(ValuesAt(sids, q.as_of))
    budget.charge_rows(len(rows))  # one per series: within the series budget, counted all the same
    for sid, iso, kind, atype, num, txt, js in rows:
        ref = refs[sid]
        key = (ref.entity_type, ref.entity_id)
        ent = entities.setdefault(key, {"id": ref.entity_id, "type": ref.entity_type})
        if iso > modified.get(key, ""):
            modified[key] = iso
        value = decode(kind, num, txt, js)
        paths = [ValuePath(ref.attr)] if wanted is None else wanted.get(ref.attr, [])
        # As of an instant, each attribute says when its value was taken (NGSIv2's dateModified metadata).
        when = {} if q.as_of is None else {"metadata": {"dateModified": {"type": "DateTime", "value": iso}}}
        for vp in paths:
            if vp.steps:
                inner = extract(value, vp.steps)
                ent[vp.text] = {"type": json_type_name(inner), "value": inner, **when}
            else:
                ent[vp.text] = {"type": atype, "value": value, **when}
    out = []
    for key in sorted(entities, key=lambda k: (k[1], k[0])):
        ent = entities[key]
        head = {"id": ent.pop("id"), "type": ent.pop("type")}
        ordered = {name: ent[name] for name in sorted(ent)}
        out.append({**head, **ordered, "dateModified": {"type": "DateTime", "value": modified[key]}})
    return out


# --- deletes ------------------------------------------------------------------------------------


def delete_target(querier: HistoryReads, q: DeleteQuery) -> tuple[list[int], TimeRange]:
    """The series ids a delete applies to; raises QuantumLeap's 404 or 409."""
    if q.entities.ids is not None:
        refs = resolve_entity_series(querier, q.scope, q.entities, None)
    else:
        refs = querier.series(SeriesSelect(q.scope, q.entities))
    sids = [r.sid for r in refs]
    if not sids or querier.count(SamplesIn(sids, q.time)) == 0:
        raise not_found()
    return sids, q.time
