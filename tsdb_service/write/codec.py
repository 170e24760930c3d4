"""Accepted notifications as ingest-log records, and back.

A record is one ``AppendSamples``: its entities as parsed and validated
(``core.model``), each with the row id the log gave it, and the identities
of the MQTT messages they came from (``deliveries``, version 2 on; a
version 1 record has none). It is a JSON object ``{"v", "dedup",
"entities", "deliveries"?}`` that orjson writes in C (times as ISO 8601
with microseconds, kinds as their codes); the log writer encodes every
notification while the lock of the interpreter is held, so the layout is
the cheapest to write: since version 3 each entity and each attribute is an
array of its fields in a fixed order (``ENTITY_FIELDS``, ``ATTR_FIELDS``; a location
an array of ``Geometry``'s fields), and an attribute's five NGSI-LD fields
(``LD_FIELDS``) are left out when all are null, as they are for every NGSIv2
sample. Versions 1 and 2 wrote the dataclasses as objects (field names as
keys); their records still read. Decoding only happens when a log is
replayed after a crash. ``VERSION`` changes whenever the layout does, and a
record of another version is refused rather than guessed.
"""

from __future__ import annotations

from datetime import datetime
from typing import Any

import orjson

from tsdb_service.core.model import AttrSample, EntitySample, Geometry, Kind
from tsdb_service.write.ops import AppendSamples, Delivery

VERSION = 3
READABLE = (1, 2, 3)  # 1: before MQTT deliveries; 1 and 2: entities and attributes as objects

# Version 3's arrays: the fields of each, in order.
ENTITY_FIELDS = ("tenant", "service_path", "entity_id", "entity_type", "time_index", "attrs", "deleted_at", "rid")
ATTR_FIELDS = ("name", "ngsi_type", "kind", "num", "txt", "js", "geo", "md")
LD_FIELDS = (
    "observed_at",
    "created_at",
    "modified_at",
    "deleted_at",
    "dataset_id",
)  # after ATTR_FIELDS, when one is set


_KINDS = {kind.value: kind for kind in Kind}


class RecordError(ValueError):
    """A log record this version cannot read."""


def encode(op: AppendSamples) -> bytes:
    entities = [
        (e.tenant, e.service_path, e.entity_id, e.entity_type, e.time_index, _attr_rows(e.attrs), e.deleted_at, e.rid)
        for e in op.entities
    ]
    doc: dict[str, Any] = {"v": VERSION, "dedup": op.dedup, "entities": entities}
    if op.deliveries:
        doc["deliveries"] = [
            (d.client_id, d.seq, d.packet_id, d.digest.hex(), d.received_at, d.prune_below) for d in op.deliveries
        ]
    return orjson.dumps(doc)


def decode(payload: bytes) -> AppendSamples:
    doc = orjson.loads(payload)
    if not isinstance(doc, dict) or doc.get("v") not in READABLE:
        raise RecordError(f"an ingest-log record of version {doc.get('v') if isinstance(doc, dict) else '?'}")
    deliveries = tuple(
        Delivery(client, seq, packet, bytes.fromhex(digest), datetime.fromisoformat(at), prune)
        for client, seq, packet, digest, at, prune in doc.get("deliveries", ())
    )
    entity = _entity if doc["v"] == VERSION else _entity_object
    return AppendSamples([entity(e) for e in doc["entities"]], dedup=bool(doc["dedup"]), deliveries=deliveries)


def _attr_rows(attrs: list[AttrSample]) -> list[tuple]:
    rows = []
    for a in attrs:
        g = a.geo
        row: tuple = (
            a.name,
            a.ngsi_type,
            a.kind,
            a.num,
            a.txt,
            a.js,
            None if g is None else (g.geojson, g.lon, g.lat, g.min_lon, g.min_lat, g.max_lon, g.max_lat),
            a.md,
        )
        if not (
            a.observed_at is None
            and a.created_at is None
            and a.modified_at is None
            and a.deleted_at is None
            and a.dataset_id is None
        ):
            row += (a.observed_at, a.created_at, a.modified_at, a.deleted_at, a.dataset_id)
        rows.append(row)
    return rows


def _entity(row: list[Any]) -> EntitySample:
    tenant, service_path, entity_id, entity_type, time_index, attrs, deleted_at, rid = row
    return EntitySample(
        tenant,
        service_path,
        entity_id,
        entity_type,
        _time(time_index),  # type: ignore[arg-type]
        [_attr(a) for a in attrs],
        _time(deleted_at),
        rid,
    )


def _attr(row: list[Any]) -> AttrSample:
    if len(row) == len(ATTR_FIELDS):  # no NGSI-LD field: the model's defaults
        name, ngsi_type, kind, num, txt, js, geo, md = row
        return AttrSample(name, ngsi_type, _kind(kind), num, txt, js, None if geo is None else Geometry(*geo), md)
    name, ngsi_type, kind, num, txt, js, geo, md, observed_at, created_at, modified_at, deleted_at, dataset_id = row
    return AttrSample(
        name,
        ngsi_type,
        _kind(kind),
        num,
        txt,
        js,
        None if geo is None else Geometry(*geo),
        md,
        _time(observed_at),
        _time(created_at),
        _time(modified_at),
        _time(deleted_at),
        dataset_id,
    )


def _kind(code: int) -> Kind:
    """``Kind(code)`` without its Python call for a known code; ValueError for an unknown one."""
    kind = _KINDS.get(code)
    return Kind(code) if kind is None else kind


def _entity_object(e: dict[str, Any]) -> EntitySample:
    """An entity of a version 1 or 2 record."""
    return EntitySample(
        e["tenant"],
        e["service_path"],
        e["entity_id"],
        e["entity_type"],
        _time(e["time_index"]),  # type: ignore[arg-type]
        [_attr_object(a) for a in e["attrs"]],
        _time(e["deleted_at"]),
        e["rid"],
    )


def _attr_object(a: dict[str, Any]) -> AttrSample:
    g = a["geo"]
    return AttrSample(
        a["name"],
        a["ngsi_type"],
        Kind(a["kind"]),
        a["num"],
        a["txt"],
        a["js"],
        None if g is None else Geometry(**g),
        a["md"],
        _time(a["observed_at"]),
        _time(a["created_at"]),
        _time(a["modified_at"]),
        _time(a["deleted_at"]),
        a["dataset_id"],
    )


def _time(text: str | None) -> datetime | None:
    return None if text is None else datetime.fromisoformat(text)
