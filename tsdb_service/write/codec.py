"""Accepted notifications as ingest-log records, and back.

A record is one ``AppendSamples``: its entities as parsed and validated
(``core.model``), each with the row id the log gave it, and the identities
of the MQTT messages they came from (``deliveries``, version 2 on; a
version 1 record has none). orjson writes the
dataclasses in C (times as ISO 8601 with microseconds, kinds as their codes),
so encoding costs the request path a few microseconds; decoding only happens
when a log is replayed after a crash. ``VERSION`` changes whenever the
layout does, and a record of another version is refused rather than guessed.
"""

from __future__ import annotations

from datetime import datetime
from typing import Any

import orjson

from tsdb_service.core.model import AttrSample, EntitySample, Geometry, Kind
from tsdb_service.write.ops import AppendSamples, Delivery

VERSION = 2
READABLE = (1, 2)  # 1: before MQTT deliveries


class RecordError(ValueError):
    """A log record this version cannot read."""


def encode(op: AppendSamples) -> bytes:
    doc: dict[str, Any] = {"v": VERSION, "dedup": op.dedup, "entities": op.entities}
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
    return AppendSamples([_entity(e) for e in doc["entities"]], dedup=bool(doc["dedup"]), deliveries=deliveries)


def _entity(e: dict[str, Any]) -> EntitySample:
    return EntitySample(
        e["tenant"],
        e["service_path"],
        e["entity_id"],
        e["entity_type"],
        _time(e["time_index"]),  # type: ignore[arg-type]
        [_attr(a) for a in e["attrs"]],
        _time(e["deleted_at"]),
        e["rid"],
    )


def _attr(a: dict[str, Any]) -> AttrSample:
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
