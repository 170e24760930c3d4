"""NGSI attribute types and values → storage ``Kind``.

The declared NGSI type picks the kind when we know it (``Number``,
``Boolean``, ``geo:point``...; matched case-insensitively, stored as
declared). When the type is missing (keyValues, values) or unknown
(NGSI-LD ``Property``, custom types) the kind is inferred from the JSON value.

Leniency rules, because a notification is history we must not lose:

* A value that does not fit its declared type is kept, never rejected:
  strings become TEXT, anything else is inferred from the value. So
  ``"n/a"`` under ``Number`` is TEXT and ``21.5`` under ``Integer`` is NUMBER.
* ``Number`` with a JSON integer stays NUMBER (``num`` = the float of it):
  the declared type wins so a column does not flip kinds per sample. Only
  undeclared integers (keyValues) are inferred as INTEGER, with NGSI type
  ``Number`` as Orion itself would report.
* Invalid geo (bad numbers, out-of-range coordinates, unclosed rings,
  malformed GeoJSON) is stored as STRUCTURED when the value is an object or
  array and TEXT when it is a string, keeping the declared type; it is just
  not queryable by location.
* FIROS values (ROS message types such as ``std_msgs.msg.String``) are
  Python dict literals with percent-encoded quotes; they are decoded with
  ``ast.literal_eval`` (never ``eval``) into STRUCTURED JSON, or kept as TEXT
  when they do not decode to a dict.
"""

from __future__ import annotations

import ast
import math
import re
from collections.abc import Callable
from typing import Any
from urllib.parse import unquote

import orjson

from tsdb_service.core.errors import ParseError
from tsdb_service.core.model import AttrSample, Kind
from tsdb_service.geo import encodings as geo
from tsdb_service.parse.timeindex import parse_time

# ROS message types as FIROS writes them: "nav_msgs.msg.Odometry" (and the
# ROS 2 spelling "nav_msgs/msg/Odometry").
_ROS_TYPE = re.compile(r"[A-Za-z][A-Za-z0-9_]*[./]msg[./][A-Za-z][A-Za-z0-9_]*\Z")

# Past this a FIROS literal is not a ROS message we can sensibly decode.
_FIROS_MAX_CHARS = 1 << 20
_FIROS_MAX_DEPTH = 64

_TRUE_FALSE = {"true": True, "false": False}

# How deep a stored value (or metadata object) may nest objects and arrays.
# Answers wrap a value in at most ~10 levels of their own (``/v2/attrs``,
# Grafana frames) and the encoder stops at 254, so everything accepted under
# this limit can be rendered on every read path. ROS messages, the deepest
# values seen in practice, nest fewer than 10 levels.
MAX_DEPTH = 100
_TOO_DEEP = f"value or metadata nested more than {MAX_DEPTH} levels deep (objects and arrays); not stored"

Handler = Callable[[str, str, Any, "str | None"], AttrSample]


def attr_sample(name: str, ngsi_type: str | None, value: Any, md: str | None) -> AttrSample:
    """The stored form of one attribute value (``ngsi_type`` None = infer)."""
    if value is None:
        return AttrSample(name, ngsi_type or "None", Kind.NULL, md=md)
    if name == "location" and geo.looks_like_geojson(value):
        # QuantumLeap treats "location" as the entity's position whatever it
        # is declared as; keep that so geo queries find such entities.
        geometry = geo.from_geojson(value)
        if geometry is not None:
            return AttrSample(name, ngsi_type or "geo:json", Kind.GEO, js=to_json(value), geo=geometry, md=md)
    if not ngsi_type:
        return _infer(name, None, value, md)
    handler = _HANDLERS.get(ngsi_type) or _HANDLERS.get(ngsi_type.lower())
    if handler is None:
        if "msg" in ngsi_type and _ROS_TYPE.match(ngsi_type):
            handler = _firos
        else:
            return _infer(name, ngsi_type, value, md)
    return handler(name, ngsi_type, value, md)


class TooDeep(ParseError):
    """A value over the nesting limit (the parser adds where it was)."""


def to_json(value: Any) -> str:
    """Compact JSON text, keys in received order, at most ``MAX_DEPTH`` deep.

    Every stored value and metadata object passes here, so this is where the
    nesting limit is enforced: a deeper value would be accepted and then
    break every read that includes it (the response encoder stops at 254
    levels, and an answer wraps the value in a few levels of its own).
    """
    try:
        text = orjson.dumps(value).decode()
    except orjson.JSONEncodeError:
        raise TooDeep(_TOO_DEEP) from None
    # Depth cannot exceed the number of brackets: most values stop here.
    if text.count("[") + text.count("{") > MAX_DEPTH and _deeper_than(value, MAX_DEPTH):
        raise TooDeep(_TOO_DEEP)
    return text


def _deeper_than(value: Any, limit: int) -> bool:
    """Whether ``value`` nests more than ``limit`` objects or arrays, walked
    level by level (no recursion: the caller may be deep in its own)."""
    level = [value] if type(value) is dict or type(value) is list else []
    depth = 0
    while level:
        depth += 1
        if depth > limit:
            return True
        inner = []
        for item in level:
            for child in item.values() if type(item) is dict else item:
                if type(child) is dict or type(child) is list:
                    inner.append(child)
        level = inner
    return False


def parse_number(value: Any) -> float | None:
    """A finite float from a JSON number or numeric string, else None."""
    kind = type(value)
    if kind is float:
        return value if math.isfinite(value) else None
    if kind is int:
        return float(value)
    if kind is not str or "_" in value:
        return None
    try:
        number = float(value)
    except ValueError:
        return None
    return number if math.isfinite(number) else None


def decode_firos(text: str) -> Any | None:
    """FIROS' percent-encoded Python dict literal → plain JSON data, or None."""
    if len(text) > _FIROS_MAX_CHARS:
        return None
    try:
        decoded = ast.literal_eval(unquote(text))
    except Exception:  # literal_eval raises many types on hostile input
        return None
    if type(decoded) is not dict:
        return None
    try:
        return _plain(decoded, 0)
    except RecursionError:
        return None


# --- handlers per declared type ------------------------------------------------


def _number(name: str, ngsi_type: str, value: Any, md: str | None) -> AttrSample:
    number = None if type(value) is bool else parse_number(value)
    if number is None:
        return _mismatch(name, ngsi_type, value, md)
    return AttrSample(name, ngsi_type, Kind.NUMBER, num=number, md=md)


def _integer(name: str, ngsi_type: str, value: Any, md: str | None) -> AttrSample:
    number = None if type(value) is bool else parse_number(value)
    if number is None:
        return _mismatch(name, ngsi_type, value, md)
    kind = Kind.INTEGER if number.is_integer() else Kind.NUMBER
    return AttrSample(name, ngsi_type, kind, num=number, md=md)


def _boolean(name: str, ngsi_type: str, value: Any, md: str | None) -> AttrSample:
    kind = type(value)
    if kind is bool:
        return _bool_sample(name, ngsi_type, value, md)
    if kind is str and value.lower() in _TRUE_FALSE:
        return _bool_sample(name, ngsi_type, _TRUE_FALSE[value.lower()], md)
    if kind is int and value in (0, 1):
        return _bool_sample(name, ngsi_type, value == 1, md)
    return _mismatch(name, ngsi_type, value, md)


def _text(name: str, ngsi_type: str, value: Any, md: str | None) -> AttrSample:
    if type(value) is str:
        return AttrSample(name, ngsi_type, Kind.TEXT, txt=value, md=md)
    return _infer(name, ngsi_type, value, md)


def _datetime(name: str, ngsi_type: str, value: Any, md: str | None) -> AttrSample:
    moment = parse_time(value)
    if moment is None:
        return _mismatch(name, ngsi_type, value, md)
    text = value if type(value) is str else moment.isoformat().replace("+00:00", "Z")
    return AttrSample(name, ngsi_type, Kind.DATETIME, num=moment.timestamp(), txt=text, md=md)


def _structured(name: str, ngsi_type: str, value: Any, md: str | None) -> AttrSample:
    if type(value) is dict or type(value) is list:
        return AttrSample(name, ngsi_type, Kind.STRUCTURED, js=to_json(value), md=md)
    return _infer(name, ngsi_type, value, md)


def _relationship(name: str, ngsi_type: str, value: Any, md: str | None) -> AttrSample:
    if type(value) is str:
        return AttrSample(name, ngsi_type, Kind.RELATIONSHIP, txt=value, md=md)
    return _mismatch(name, ngsi_type, value, md)


def _geo(name: str, ngsi_type: str, value: Any, md: str | None) -> AttrSample:
    geometry = geo.from_ngsi(ngsi_type.lower(), value)
    if geometry is None:
        return _mismatch(name, ngsi_type, value, md)
    return AttrSample(name, ngsi_type, Kind.GEO, js=to_json(value), geo=geometry, md=md)


def _firos(name: str, ngsi_type: str, value: Any, md: str | None) -> AttrSample:
    if type(value) is str:
        decoded = decode_firos(value)
        if decoded is None:
            return AttrSample(name, ngsi_type, Kind.TEXT, txt=value, md=md)
        return AttrSample(name, ngsi_type, Kind.STRUCTURED, js=to_json(decoded), md=md)
    return _infer(name, ngsi_type, value, md)


# --- inference -----------------------------------------------------------------


def _mismatch(name: str, ngsi_type: str, value: Any, md: str | None) -> AttrSample:
    """Value does not fit its declared type: keep it rather than guess a date."""
    if type(value) is str:
        return AttrSample(name, ngsi_type, Kind.TEXT, txt=value, md=md)
    return _infer(name, ngsi_type, value, md)


def _infer(name: str, ngsi_type: str | None, value: Any, md: str | None) -> AttrSample:
    """Kind from the JSON value; the NGSI type defaults to Orion's names."""
    kind = type(value)
    if kind is str:
        moment = parse_time(value)
        if moment is None:
            return AttrSample(name, ngsi_type or "Text", Kind.TEXT, txt=value, md=md)
        return AttrSample(name, ngsi_type or "DateTime", Kind.DATETIME, num=moment.timestamp(), txt=value, md=md)
    if kind is bool:
        return _bool_sample(name, ngsi_type or "Boolean", value, md)
    if kind is int:
        return AttrSample(name, ngsi_type or "Number", Kind.INTEGER, num=float(value), md=md)
    if kind is float:
        return AttrSample(name, ngsi_type or "Number", Kind.NUMBER, num=value, md=md)
    if value is None:
        return AttrSample(name, ngsi_type or "None", Kind.NULL, md=md)
    return AttrSample(name, ngsi_type or "StructuredValue", Kind.STRUCTURED, js=to_json(value), md=md)


def _bool_sample(name: str, ngsi_type: str, value: bool, md: str | None) -> AttrSample:
    if value:
        return AttrSample(name, ngsi_type, Kind.BOOLEAN, num=1.0, js="true", md=md)
    return AttrSample(name, ngsi_type, Kind.BOOLEAN, num=0.0, js="false", md=md)


def _plain(value: Any, depth: int) -> Any:
    """Python literal → JSON-compatible data (tuples/sets → lists, bytes → str,
    non-finite floats → null, ints beyond 64 bits → float)."""
    if depth > _FIROS_MAX_DEPTH:
        raise RecursionError("FIROS literal nested too deeply")
    kind = type(value)
    if kind is dict:
        return {k if type(k) is str else str(k): _plain(v, depth + 1) for k, v in value.items()}
    if kind in (list, tuple, set, frozenset):
        return [_plain(v, depth + 1) for v in value]
    if kind is float:
        return value if math.isfinite(value) else None
    if kind is int:
        return value if -(1 << 63) <= value < (1 << 64) else float(value)
    if kind is bytes:
        return value.decode("utf-8", "replace")
    if kind in (str, bool) or value is None:
        return value
    return str(value)  # complex, Ellipsis: keep something readable


def _table() -> dict[str, Handler]:
    groups: dict[Handler, tuple[str, ...]] = {
        _number: ("Number", "Float", "Double", "Decimal", "Real"),
        _integer: ("Integer", "Int", "Long"),
        _boolean: ("Boolean", "Bool"),
        _text: ("Text", "String", "URL", "URI", "Email"),
        _datetime: ("DateTime", "ISO8601", "Date"),
        _structured: ("StructuredValue", "Object", "Array", "Json", "JsonProperty", "List"),
        _relationship: ("Relationship",),
        _geo: ("geo:json", "geo:point", "geo:line", "geo:box", "geo:polygon", "GeoProperty"),
    }
    table: dict[str, Handler] = {}
    for handler, names in groups.items():
        for type_name in names:
            table[type_name] = handler
            table[type_name.lower()] = handler
    return table


_HANDLERS = _table()
