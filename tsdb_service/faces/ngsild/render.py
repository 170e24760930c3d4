"""Instances → the three temporal representations (ETSI GS CIM 009 clause 4.5.7-4.5.9, 4.5.19).

* normalized: each attribute an array of instances, each with its type,
  value (``value``/``object``/``languageMap``/...), ``instanceId``,
  ``observedAt``, sub-properties, and ``datasetId`` when not the default;
* simplified (``temporalValues``): per attribute and datasetId one object
  with ``values`` (``objects``, ``languageMaps``, ``valueLists``, ...) as
  ``[value, time]`` pairs, the time being the query's time property;
* aggregated (``aggregatedValues``): per attribute and datasetId one object
  with one ``[value, periodStart, periodEnd]`` list per method.

An attribute with one datasetId is an object (normalized: a list); with
several, a list of objects. NGSIv2 samples read as Properties (Relationship
and GeoProperty when their type says so); their metadata become Property
sub-properties.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass
from datetime import datetime
from typing import Any

import orjson

from tsdb_service.core.model import client_instance_id, instance_urn
from tsdb_service.faces.ngsild.aggregate import iso, type_name
from tsdb_service.history.service import decode

LD_NULL = "urn:ngsi-ld:null"
# attribute type → (member of one instance, member of the simplified form)
MEMBERS = {
    "Property": ("value", "values"),
    "GeoProperty": ("value", "values"),
    "Relationship": ("object", "objects"),
    "LanguageProperty": ("languageMap", "languageMaps"),
    "ListProperty": ("valueList", "valueLists"),
    "ListRelationship": ("objectList", "objectLists"),
    "VocabProperty": ("vocab", "vocabs"),
    "JsonProperty": ("json", "jsons"),
}
# In the simplified form these values keep their member (Stellio's form, the
# one the ETSI suite checks): [{"languageMap": {...}}, time], [{"json": ...},
# time], [{"vocab": "..."}, time]; a bare object could not be told from a
# Property's value.
WRAPPED = frozenset({"LanguageProperty", "JsonProperty", "VocabProperty"})
_CONCISE_DROPS = frozenset(MEMBERS) - {"GeoProperty"}
_OWN_MEMBERS = frozenset(
    {"type", "observedAt", "createdAt", "modifiedAt", "deletedAt", "datasetId", "instanceId"}
    | {m for pair in MEMBERS.values() for m in pair}
)


def ld_type(row) -> str:
    return type_name(row.atype, row.kind)


def value_of(row, attr_type: str) -> Any:
    if row.deleted_at is not None:
        return {"@none": LD_NULL} if attr_type == "LanguageProperty" else LD_NULL
    return decode(row.kind, row.num, row.txt, row.js)


def sub_properties(row) -> dict:
    """The instance's other members: NGSI-LD sub-properties (``unitCode``,
    nested Properties) as received; NGSIv2 metadata as Properties."""
    if not row.md:
        return {}
    try:
        meta = orjson.loads(row.md)
    except orjson.JSONDecodeError:
        return {}
    if not isinstance(meta, dict):
        return {}
    if row.atype in MEMBERS:
        return {k: v for k, v in meta.items() if k not in _OWN_MEMBERS}
    out = {}
    for name, item in meta.items():
        if isinstance(item, dict) and "value" in item:
            out[name] = {"type": "Property", "value": item["value"]}
        else:
            out[name] = {"type": "Property", "value": item}
    return out


def _time(moment: datetime | None) -> str | None:
    return None if moment is None else iso(moment)


@dataclass(frozen=True, slots=True)
class Shape:
    """How instances are written: ``sys_attrs`` adds createdAt/modifiedAt;
    ``concise`` leaves out the ``type`` a value member already says
    (clause 4.5.8; a GeoProperty keeps it, its ``value`` alone would read
    as a Property's); ``lang`` (clause 4.15, RFC 4647 ranges) turns each
    LanguageProperty instance into a Property of its best-matching
    language, with ``lang`` naming it (Stellio's rule: else ``@none``,
    else the first tag in order)."""

    sys_attrs: bool = False
    concise: bool = False
    lang: tuple[tuple[str, float], ...] | None = None


def normalized_instance(row, shape: Shape) -> dict:
    attr_type = ld_type(row)
    value = value_of(row, attr_type)
    out: dict[str, Any] = {}
    if shape.lang is not None and attr_type == "LanguageProperty" and isinstance(value, dict) and value:
        tag = best_language(value, shape.lang)
        attr_type, value = "Property", value[tag]
        out["lang"] = tag
    member = MEMBERS[attr_type][0]
    if shape.concise and attr_type != "GeoProperty":
        out = {member: value, **out}
    else:
        out = {"type": attr_type, member: value, **out}
    subs = sub_properties(row)
    out.update(concise_members(subs) if shape.concise else subs)
    out["instanceId"] = client_instance_id(row.md) or instance_urn(row.iid)
    out["observedAt"] = _time(row.observed_at or row.t)
    if row.dataset_id is not None:
        out["datasetId"] = row.dataset_id
    if row.deleted_at is not None:
        out["deletedAt"] = _time(row.deleted_at)
    if shape.sys_attrs:
        if row.created_at is not None:
            out["createdAt"] = _time(row.created_at)
        if row.modified_at is not None:
            out["modifiedAt"] = _time(row.modified_at)
    return out


def normalized(rows: list, shape: Shape) -> list[dict]:
    """One attribute's instances (all datasetIds), oldest first."""
    ordered = sorted(rows, key=lambda r: (r.at, r.iid))
    return [normalized_instance(r, shape) for r in ordered]


def concise_members(members: dict) -> dict:
    """Sub-properties and sub-relationships without the ``type`` their value member says."""
    out = {}
    for name, item in members.items():
        if isinstance(item, dict) and item.get("type") in _CONCISE_DROPS and MEMBERS[item["type"]][0] in item:
            item = {k: v for k, v in item.items() if k != "type"}
        out[name] = item
    return out


def best_language(language_map: dict, ranges: tuple[tuple[str, float], ...]) -> str:
    """The tag of ``language_map`` the ``lang`` ranges prefer (RFC 4647
    basic filtering, highest ``q`` first; ``*`` takes any), else ``@none``,
    else the first tag in order."""
    tags = sorted(language_map)
    for wanted, _ in ranges:
        for tag in tags:
            low = tag.lower()
            if wanted == "*" or low == wanted or low.startswith(wanted + "-"):
                return tag
    return tags[0]


def simplified(rows: list, lang: tuple[tuple[str, float], ...] | None = None) -> dict | list[dict]:
    """One attribute's instances as ``[value, time]`` pairs per datasetId."""
    out = []
    for dataset, group in _by_dataset(rows):
        attr_type = ld_type(group[0])
        member = MEMBERS[attr_type][0]
        values = [value_of(r, attr_type) for r in group]
        if lang is not None and attr_type == "LanguageProperty":
            attr_type, member = "Property", "value"
            values = [v[best_language(v, lang)] if isinstance(v, dict) and v else v for v in values]
        if attr_type in WRAPPED:
            pairs = [[{member: v}, iso(r.at)] for v, r in zip(values, group, strict=True)]
        else:
            pairs = [[v, iso(r.at)] for v, r in zip(values, group, strict=True)]
        item: dict[str, Any] = {"type": attr_type, MEMBERS[attr_type][1]: pairs}
        if dataset is not None:
            item["datasetId"] = dataset
        out.append(item)
    return out[0] if len(out) == 1 else out


def aggregated(series: list[tuple[str | None, str, list[list[tuple]]]], methods: Iterable[str]):
    """``series``: (datasetId, attribute type, values) per stored series of
    one attribute; ``values`` holds per method, in the order of ``methods``,
    its (value, start, end) per period: tuples (JSON arrays too), which the
    garbage collector skips, and a response holds thousands."""
    out = []
    for dataset, attr_type, values in sorted(series, key=lambda s: (s[0] is not None, s[0] or "")):
        item: dict[str, Any] = {"type": attr_type}
        for method, periods in zip(methods, values, strict=True):
            item[method] = periods
        if dataset is not None:
            item["datasetId"] = dataset
        out.append(item)
    return out[0] if len(out) == 1 else out


def _by_dataset(rows: list) -> list[tuple[str | None, list]]:
    groups: dict[str | None, list] = {}
    for row in sorted(rows, key=lambda r: (r.at, r.iid)):
        groups.setdefault(row.dataset_id, []).append(row)
    return sorted(groups.items(), key=lambda item: (item[0] is not None, item[0] or ""))


def entity(
    entity_id: str,
    types: list[str],
    attrs: dict[str, Any],
    pick: tuple | None,
    omit: tuple | None,
    compact: Callable[[str], str],
) -> dict:
    """One temporal entity; ``attrs`` maps attribute IRIs to their rendering."""
    show = (lambda member: member in pick) if pick is not None else (lambda member: True)
    hidden = set(omit or ())
    out: dict[str, Any] = {}
    if show("id") and "id" not in hidden:
        out["id"] = entity_id
    if show("type") and "type" not in hidden:
        out["type"] = types[0] if len(types) == 1 else types
    for iri in sorted(attrs, key=compact):
        out[compact(iri)] = attrs[iri]
    return out
