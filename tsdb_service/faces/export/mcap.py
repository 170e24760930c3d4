"""Record batches → an MCAP file that Foxglove opens (``export --format mcap``).

One channel per entity and attribute (topic ``[SERVICE_PATH]/ENTITY_ID/ATTRIBUTE``),
JSON message encoding with a JSON Schema per channel, each message's log
and publish time the sample's time (nanoseconds). What a sample becomes:

* a position (a geo sample whose geometry is a Point: ``geo:json``,
  ``geo:point``, an NGSI-LD GeoProperty, QuantumLeap's ``location``) is a
  ``foxglove.LocationFix``, so the Map panel draws the track; the value as
  stored rides along in its ``metadata`` (``ngsi_value``);
* another geometry is a ``foxglove.GeoJSON`` (the Map panel draws it too),
  with the stored value in ``ngsi_value``;
* an object (a ROS message, as the ROS 2 IoT Agent or ``import rosbag``
  stored it) is the message itself, its schema named after the ROS type
  when the NGSI type is one (``nav_msgs/msg/Odometry``), so what came from
  a bag leaves as the same messages;
* anything else (numbers, text, booleans, arrays, null, and an object whose
  only member is ``value``) is ``{"value": V}``, which Foxglove's Plot panel
  reads as ``/topic.value``.

Each channel's metadata names the series (``tsdb.service``,
``tsdb.service_path``, ``tsdb.entity_id``, ``tsdb.entity_type``,
``tsdb.attribute``, ``tsdb.ngsi_type``), so ``tsdb-service import rosbag``
reads an exported file back into the same series (``commands.rosbag``).
A channel's schema is inferred from its first sample; an attribute whose
samples change type or shape (a number, later text) gets one channel per
type and shape on the same topic.

Memory: the writer's current chunk (1 MiB) and one entry per chunk and
channel in its index; the batch being encoded.
"""

from __future__ import annotations

import math
import re
from typing import IO, Any, cast

import orjson
import pyarrow as pa

from tsdb_service import __version__
from tsdb_service.faces.export.pieces import Pieces
from tsdb_service.geo.encodings import from_ngsi

MEDIA_TYPE = "application/x-mcap"
LOCATION_FIX = "foxglove.LocationFix"
GEOJSON = "foxglove.GeoJSON"
_GEO_TYPES = frozenset({"geo:json", "geo:point", "geo:line", "geo:box", "geo:polygon", "geoproperty"})
_ROS_TYPE = re.compile(r"([A-Za-z][A-Za-z0-9_]*)[./]msg[./]([A-Za-z][A-Za-z0-9_]*)\Z")
_SCHEMA_DEPTH = 32  # deeper than any ROS message; past it: any value

# Forms of a message (a channel has one).
_MESSAGE, _VALUE, _LOCATION, _GEOMETRY = "message", "value", "location", "geometry"

_TIME = {
    "type": "object",
    "title": "time",
    "properties": {"sec": {"type": "integer", "minimum": 0}, "nsec": {"type": "integer", "minimum": 0}},
}
LOCATION_FIX_SCHEMA = {
    "title": LOCATION_FIX,
    "description": "A navigation satellite fix for any Global Navigation Satellite System",
    "type": "object",
    "properties": {
        "timestamp": _TIME,
        "frame_id": {"type": "string"},
        "latitude": {"type": "number", "description": "Latitude in degrees"},
        "longitude": {"type": "number", "description": "Longitude in degrees"},
        "altitude": {"type": "number", "description": "Altitude in meters"},
        "position_covariance": {"type": "array", "items": {"type": "number"}, "minItems": 9, "maxItems": 9},
        "position_covariance_type": {"type": "integer", "minimum": 0, "maximum": 3},
        "metadata": {
            "type": "array",
            "items": {
                "type": "object",
                "properties": {"key": {"type": "string"}, "value": {"type": "string"}},
            },
        },
    },
}
GEOJSON_SCHEMA = {
    "title": GEOJSON,
    "description": "GeoJSON data for annotating maps",
    "type": "object",
    "properties": {"geojson": {"type": "string"}, "ngsi_value": {"type": "string"}},
}
_NO_COVARIANCE = [0.0] * 9


class McapEncoder:
    """``encode(batch)`` (export columns, oldest first) → the bytes it adds; ``finish()`` → the rest."""

    def __init__(self, tenant: str = "") -> None:
        from mcap.writer import CompressionType, Writer

        self._tenant = tenant
        self._sink = Pieces()
        self._writer = Writer(cast(IO[Any], self._sink), compression=CompressionType.ZSTD)  # it writes and tells
        self._writer.start(profile="", library=f"tsdb-service {__version__}")
        self._channels: dict[tuple, tuple[int, list[int]]] = {}  # key → (channel id, [next sequence])

    def encode(self, batch: pa.RecordBatch) -> bytes:
        if batch.num_rows:
            micros = batch.column(0).cast(pa.int64()).to_pylist()
            columns = [batch.column(i).to_pylist() for i in range(1, batch.num_columns)]
            for at, row in zip(micros, zip(*columns, strict=True), strict=True):
                self._sample(at * 1000, *row)
        return self._sink.take()

    def finish(self) -> bytes:
        self._writer.finish()
        return self._sink.take()

    def _sample(self, time_ns: int, entity_id, entity_type, service_path, attr, ngsi_type, num, txt, flag, js) -> None:
        value = orjson.loads(js) if js is not None else num if num is not None else txt if txt is not None else flag
        form, message = _message(ngsi_type or "", attr, value, js, time_ns)
        key = (service_path, entity_id, entity_type, attr, ngsi_type or "", form)
        channel = self._channels.get(key)
        if channel is None:
            channel = self._channels[key] = (self._channel(key, ngsi_type or "", form, message), [0])
        channel_id, sequence = channel
        sequence[0] += 1
        self._writer.add_message(channel_id, time_ns, orjson.dumps(message), time_ns, sequence[0])

    def _channel(self, key: tuple, ngsi_type: str, form: str, message: Any) -> int:
        service_path, entity_id, entity_type, attr, _, _ = key
        if form == _LOCATION:
            name, schema = LOCATION_FIX, LOCATION_FIX_SCHEMA
        elif form == _GEOMETRY:
            name, schema = GEOJSON, GEOJSON_SCHEMA
        else:
            name = _schema_name(ngsi_type)
            schema = {"title": name, **_json_schema(message, 0)}
        schema_id = self._writer.register_schema(name, "jsonschema", orjson.dumps(schema))
        topic = f"{'' if service_path == '/' else service_path}/{entity_id}/{attr}"
        metadata = {
            "tsdb.service": self._tenant,
            "tsdb.service_path": service_path,
            "tsdb.entity_id": entity_id,
            "tsdb.entity_type": entity_type,
            "tsdb.attribute": attr,
            "tsdb.ngsi_type": ngsi_type,
        }
        return self._writer.register_channel(topic, "json", schema_id, metadata)


def _message(ngsi_type: str, attr: str, value: Any, raw: str | None, time_ns: int) -> tuple[str, Any]:
    """(form, message) of one sample (module docstring)."""
    lowered = ngsi_type.lower()
    if raw is not None and (lowered in _GEO_TYPES or (attr == "location" and type(value) is dict)):
        geometry = from_ngsi(lowered, value)
        if geometry is not None:
            shape = orjson.loads(geometry.geojson)
            if shape.get("type") == "Point":
                return _LOCATION, _location_fix(shape["coordinates"], raw, time_ns)
            return _GEOMETRY, {"geojson": geometry.geojson, "ngsi_value": raw}
    if type(value) is dict and not (len(value) == 1 and "value" in value):
        return _MESSAGE, value
    return _VALUE, {"value": value}


def _location_fix(coordinates: list[float], raw: str, time_ns: int) -> dict:
    sec, nsec = divmod(time_ns, 1_000_000_000)
    altitude = coordinates[2] if len(coordinates) > 2 and math.isfinite(coordinates[2]) else 0.0
    return {
        "timestamp": {"sec": sec, "nsec": nsec},
        "frame_id": "",
        "latitude": coordinates[1],
        "longitude": coordinates[0],
        "altitude": altitude,
        "position_covariance": _NO_COVARIANCE,
        "position_covariance_type": 0,
        "metadata": [{"key": "ngsi_value", "value": raw}],
    }


def _schema_name(ngsi_type: str) -> str:
    """The ROS type (``nav_msgs/msg/Odometry``) when the NGSI type is one
    (FIROS' ``nav_msgs.msg.Odometry`` too), else ``tsdb.<NGSI type>``."""
    found = _ROS_TYPE.match(ngsi_type)
    if found:
        return f"{found[1]}/msg/{found[2]}"
    return f"tsdb.{ngsi_type or 'None'}"


def _json_schema(value: Any, depth: int) -> dict:
    """A JSON Schema describing ``value``'s shape (numbers as ``number``:
    a field that is 0 in one message may be 0.5 in the next)."""
    if depth > _SCHEMA_DEPTH or value is None:
        return {}
    kind = type(value)
    if kind is dict:
        return {"type": "object", "properties": {k: _json_schema(v, depth + 1) for k, v in value.items()}}
    if kind is list:
        return {"type": "array", "items": _json_schema(value[0], depth + 1) if value else {}}
    if kind is bool:
        return {"type": "boolean"}
    if kind is int or kind is float:
        return {"type": "number"}
    return {"type": "string"}
