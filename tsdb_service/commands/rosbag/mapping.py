"""Which topic becomes which entity, and which message fields which attributes.

A map (YAML or TOML) for ``tsdb-service import rosbag --map MAP``::

    service: lawnmower                # tenant (Fiware-Service); default: the default tenant
    service_path: /bosch              # default /
    entity_type: ROS2System           # default ROS2Topic
    unmapped: skip                    # topics the map does not name: import (default) or skip
    topics:
      /odom:
        entity: urn:ngsiv2:ROS2System:Lawnmower01
        attribute: odom               # the whole message, as the ROS 2 IoT Agent sends it
      /fix:
        entity: urn:ngsiv2:ROS2System:Lawnmower01
        attributes:                   # message fields as attributes (value paths)
          location: {path: "", type: geo:json}    # a NavSatFix as a GeoJSON Point
          altitude: altitude
      /camera/image_raw: skip

Without a map (and for the topics it does not name, unless ``unmapped:
skip``) each topic is one entity, ``urn:ngsi-ld:ROS2Topic:`` and the topic
name with ``/`` as ``:`` (``/mower/odom`` → ``urn:ngsi-ld:ROS2Topic:mower:odom``),
of type ``ROS2Topic``, and each message one attribute named after the
topic's last part (``odom``), of type ``Object``, holding the message as
JSON, exactly as the ROS 2 IoT Agent forwards it.

A topic's keys: ``skip``, ``entity``, ``entity_type``, ``service``,
``service_path``, ``attribute`` (the whole message) or ``attributes``
(``NAME: PATH`` or ``NAME: {path, type}``; an empty path is the whole
message), ``type`` (the NGSI type of ``attribute``; default ``Object``;
``message`` stores the ROS message type, ``nav_msgs/msg/Odometry``, as
FIROS does), and ``time`` (the value path of the sample's stamp; default
``header.stamp`` when the message has a ``std_msgs/Header``, else the bag's
receive time; ``receive`` for that always). Every name follows the
service's naming rules, every path is checked against the message type's
definition, and every problem is one line naming the place in the map.
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import orjson

from tsdb_service.commands.rosbag.bag import CDR, JSON, ROS1, Recording, Topic
from tsdb_service.core.valuesteps import Steps, parse_steps, steps_text
from tsdb_service.parse.names import (
    ID_RULE,
    RULE,
    id_problem,
    name_problem,
    normalize_service_path,
    service_path_problem,
)
from tsdb_service.parse.request_context import is_stored_tenant

DEFAULT_ENTITY_TYPE = "ROS2Topic"
DEFAULT_NGSI_TYPE = "Object"  # what the ROS 2 IoT Agent declares
ENTITY_PREFIX = "urn:ngsi-ld:ROS2Topic:"
GEO_JSON = "geo:json"
MESSAGE_TYPE = "message"  # ``type: message``: the ROS message type as the NGSI type
RECEIVE = "receive"  # ``time: receive``
HEADER_STAMP: Steps = ("header", "stamp")

_TOP_KEYS = {"service", "service_path", "entity_type", "unmapped", "topics"}
_TOPIC_KEYS = {"skip", "entity", "entity_type", "service", "service_path", "attribute", "attributes", "type", "time"}
_FIELD_KEYS = {"path", "type"}


# What ``export --format mcap`` says of each channel (its metadata), so an
# exported file imports back into the same series: map key -> metadata key.
EXPORTED = {
    "service": "tsdb.service",
    "service_path": "tsdb.service_path",
    "entity": "tsdb.entity_id",
    "entity_type": "tsdb.entity_type",
    "attribute": "tsdb.attribute",
    "type": "tsdb.ngsi_type",
}


class MapError(ValueError):
    """The map cannot be used; one line naming the file and the place in it."""


@dataclass(frozen=True, slots=True)
class Field:
    """One attribute a message gives: the value at ``steps`` (``()``: the
    whole message) stored under ``name`` as ``ngsi_type``."""

    name: str
    steps: Steps
    ngsi_type: str | None  # None: inferred from each value, as for keyValues


@dataclass(frozen=True, slots=True)
class TopicPlan:
    """What one topic's messages become."""

    topic: str
    tenant: str
    service_path: str
    entity_id: str
    entity_type: str
    fields: tuple[Field, ...]
    time: Steps | None  # the stamp's path; None: the receive time

    def series(self) -> list[tuple[str, str, str, str, str]]:
        return [(self.tenant, self.service_path, self.entity_id, self.entity_type, f.name) for f in self.fields]


@dataclass(frozen=True, slots=True)
class Plan:
    """Every imported topic's plan; ``skipped`` the recording's other topics."""

    topics: dict[str, TopicPlan]
    skipped: tuple[str, ...]

    def canonical(self) -> bytes:
        """The plan as bytes: the same map gives the same bytes (part of the import's identity)."""
        return orjson.dumps([self.topics[name] for name in sorted(self.topics)])


def load_map(path: str | Path) -> dict:
    """The map file as data: TOML for ``.toml``, YAML (or JSON) otherwise."""
    where = Path(path)
    try:
        text = where.read_bytes()
    except OSError as exc:
        raise MapError(f"cannot read the map {where}: {exc.strerror or exc}") from None
    try:
        if where.suffix.lower() == ".toml":
            data: Any = tomllib.loads(text.decode())
        else:
            from ruamel.yaml import YAML

            data = YAML(typ="safe", pure=True).load(text)
    except Exception as exc:  # the parsers' own error types
        first = " ".join(str(exc).split())[:200]
        raise MapError(
            f"the map {where} is not valid {'TOML' if where.suffix == '.toml' else 'YAML'}: {first}"
        ) from None
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise MapError(f"the map {where} must be a mapping (service, topics, ...), not a {type(data).__name__}")
    return data


def plan(recording: Recording, spec: dict, source: str = "the map", defaults: dict | None = None) -> Plan:
    """The plan for ``recording`` from a loaded map (``{}``: the defaults);
    ``defaults`` are the command line's tenant and service path."""
    top = {**(defaults or {}), **spec}
    _keys(top, _TOP_KEYS, source)
    topics = top.get("topics") or {}
    if not isinstance(topics, dict):
        raise MapError(f"{source}: topics must be a mapping of topic names")
    unknown = sorted(set(topics) - set(recording.topics))
    if unknown:
        present = ", ".join(sorted(recording.topics)) or "none"
        raise MapError(f"{source}: topic {unknown[0]} is not in the bag (its topics: {present})")
    unmapped = top.get("unmapped", "import")
    if unmapped not in ("import", "skip"):
        raise MapError(f"{source}: unmapped must be import or skip, not {unmapped!r}")
    plans: dict[str, TopicPlan] = {}
    skipped = []
    for name, topic in sorted(recording.topics.items()):
        entry = topics.get(name, None if unmapped == "import" else "skip")
        where = f"{source}: topics.{name}"
        if entry == "skip" or (isinstance(entry, dict) and entry.get("skip") is True):
            skipped.append(name)
            continue
        if entry is not None and not isinstance(entry, dict):
            raise MapError(f"{where} must be a mapping or skip")
        plans[name] = _topic_plan(recording, topic, top, entry or {}, where)
    _one_type_per_series(plans, source)
    return Plan(plans, tuple(skipped))


def _topic_plan(recording: Recording, topic: Topic, top: dict, entry: dict, where: str) -> TopicPlan:
    _keys(entry, _TOPIC_KEYS, where)
    if not topic.known and topic.encoding not in (CDR, ROS1, JSON):
        raise MapError(
            f"{where}: its messages are {topic.encoding}-encoded; an MCAP file without the ros2 profile "
            "is read when its channels are JSON: skip the topic"
        )
    if not topic.known:
        raise MapError(
            f"{where}: the bag has no definition of {topic.msgtype} and it is not a standard ROS type: "
            "record with a newer rosbag2 (Iron or later stores definitions), or skip the topic"
        )
    own = {key: topic.metadata[EXPORTED[key]] for key in EXPORTED if EXPORTED[key] in topic.metadata}
    tenant = _tenant(entry.get("service", top.get("service", own.get("service", ""))), where)
    service_path = _service_path(
        entry.get("service_path", top.get("service_path", own.get("service_path", "/"))), where
    )
    entity_id = _text(entry.get("entity", own.get("entity", _default_entity(topic.name))), where + ".entity")
    default_type = top.get("entity_type", own.get("entity_type", DEFAULT_ENTITY_TYPE))
    entity_type = _text(entry.get("entity_type", default_type), where + ".entity_type")
    if "attribute" in own and "attributes" not in entry:
        entry = {"attribute": own["attribute"], "type": own.get("type", DEFAULT_NGSI_TYPE), **entry}
    for value, what in ((entity_id, "entity"), (entity_type, "entity_type")):
        problem = id_problem(value)
        if problem is not None:
            raise MapError(f"{where}.{what} {value[:80]!r} {problem} ({ID_RULE})")
    fields = _fields(recording, topic, entry, where)
    return TopicPlan(
        topic.name, tenant, service_path, entity_id, entity_type, fields, _time(recording, topic, entry, where)
    )


def _fields(recording: Recording, topic: Topic, entry: dict, where: str) -> tuple[Field, ...]:
    if "attribute" in entry and "attributes" in entry:
        raise MapError(f"{where}: give attribute (the whole message) or attributes (fields), not both")
    if "attributes" not in entry:
        name = _text(entry.get("attribute", _default_attribute(topic.name)), where + ".attribute")
        ngsi_type = _ngsi_type(entry.get("type", DEFAULT_NGSI_TYPE), topic, where + ".type")
        return (_checked_field(recording, topic, name, (), ngsi_type, where + ".attribute"),)
    if "type" in entry:
        raise MapError(f"{where}.type: with attributes, each attribute says its type ({{path, type}})")
    attributes = entry["attributes"]
    if not isinstance(attributes, dict) or not attributes:
        raise MapError(f"{where}.attributes must map attribute names to message fields")
    out = []
    for name, spec in attributes.items():
        place = f"{where}.attributes.{name}"
        given: Any = spec.get("type") if isinstance(spec, dict) else None
        if isinstance(spec, dict):
            _keys(spec, _FIELD_KEYS, place)
        path = _text(spec.get("path", "") if isinstance(spec, dict) else spec, place, empty=True)
        try:
            steps = parse_steps(path)
        except ValueError as exc:
            raise MapError(f"{place}: {exc}") from None
        node = _walk(recording, topic, steps, place)
        kind = _inferred(node) if given is None else _ngsi_type(given, topic, place + ".type")
        out.append(_checked_field(recording, topic, str(name), steps, kind, place))
    return tuple(out)


def _checked_field(
    recording: Recording, topic: Topic, name: str, steps: Steps, ngsi_type: str | None, place: str
) -> Field:
    problem = name_problem(name)
    if problem is not None:
        raise MapError(f"{place}: attribute name {name[:80]!r} {problem} ({RULE})")
    node = _walk(recording, topic, steps, place)
    if ngsi_type == GEO_JSON and node is not None and not _has_position(recording, node):
        raise MapError(
            f"{place}: geo:json needs a message with latitude and longitude (a sensor_msgs/NavSatFix) "
            f"at {steps_text(steps) or 'the message'}"
        )
    return Field(name, steps, ngsi_type)


def _walk(recording: Recording, topic: Topic, steps: Steps, place: str):
    """Follow ``steps`` through the message type's definition: the node
    reached (``("msg", type)``, ``("base", type)`` or ``("array", node)``),
    or None for JSON topics (no definition to check against)."""
    from rosbags.typesys.store import Nodetype

    if recording.fields(topic.msgtype) is None:
        return None
    node: tuple = ("msg", topic.msgtype)
    done: list[str | int] = []
    for step in steps:
        here = steps_text(tuple(done)) or "the message"
        if isinstance(step, int):
            if node[0] != "array":
                raise MapError(f"{place}: {here} in {topic.msgtype} is not an array, [{step}] cannot follow it")
            size, inner = node[1], node[2]
            if size and step >= size:
                raise MapError(f"{place}: {here} in {topic.msgtype} has {size} elements, [{step}] is past them")
            node = inner
        else:
            fields = recording.fields(node[1]) if node[0] == "msg" else None
            names = [n for n, _ in fields or []]
            if step not in names:
                detail = f" (its fields: {', '.join(names)})" if names else ""
                raise MapError(
                    f"{place}: the field {steps_text((*done, step))} does not exist in {topic.msgtype}: "
                    f"{here} has no field {step!r}{detail}"
                )
            kind, detail_ = dict(fields or [])[step]
            node = _node(kind, detail_, Nodetype)
        done.append(step)
    return node


def _node(kind, detail, nodetype) -> tuple:
    if kind == nodetype.NAME:
        return ("msg", detail)
    if kind == nodetype.BASE:
        return ("base", detail[0])
    inner_kind, inner_detail = detail[0]
    size = detail[1] if kind == nodetype.ARRAY else 0
    return ("array", size, _node(inner_kind, inner_detail, nodetype))


def _has_position(recording: Recording, node: tuple) -> bool:
    if node[0] != "msg":
        return False
    names = {n for n, _ in recording.fields(node[1]) or []}
    return {"latitude", "longitude"} <= names


def _inferred(node: tuple | None) -> str | None:
    """The NGSI type of a field: Number, Boolean, Text for plain values, as
    Orion infers; Object for messages and arrays; None (inferred from each
    value) for JSON topics, whose fields no definition describes."""
    if node is None:
        return None
    if node[0] != "base":
        return DEFAULT_NGSI_TYPE
    base = node[1]
    if base == "bool":
        return "Boolean"
    if base in ("string", "wstring"):
        return "Text"
    return "Number"


def _time(recording: Recording, topic: Topic, entry: dict, where: str) -> Steps | None:
    given = entry.get("time")
    if given == RECEIVE:
        return None
    if given is None:
        if recording.fields(topic.msgtype) is None:
            return None  # JSON (an MCAP export): the log time is the sample's time
        fields = dict(recording.fields(topic.msgtype) or [])
        header = fields.get("header")
        if header is None or header[1] != "std_msgs/msg/Header":
            return None
        return HEADER_STAMP
    text = _text(given, where + ".time")
    try:
        steps = parse_steps(text)
    except ValueError as exc:
        raise MapError(f"{where}.time: {exc}") from None
    if not steps:
        raise MapError(f"{where}.time: give the stamp's path (header.stamp) or receive")
    _walk(recording, topic, steps, where + ".time")
    return steps


def _ngsi_type(value: Any, topic: Topic, where: str) -> str:
    text = _text(value, where)
    if text == MESSAGE_TYPE:
        return topic.msgtype or DEFAULT_NGSI_TYPE
    return text


def _one_type_per_series(plans: dict[str, TopicPlan], source: str) -> None:
    """Two topics may share an entity, never an attribute of it."""
    seen: dict[tuple, str] = {}
    for name, topic_plan in sorted(plans.items()):
        for series in topic_plan.series():
            other = seen.setdefault(series, name)
            if other != name:
                raise MapError(
                    f"{source}: topics {other} and {name} both write attribute {series[4]!r} of {series[2]}: "
                    "give each its own attribute name"
                )


def _default_entity(topic: str) -> str:
    return ENTITY_PREFIX + topic.strip("/").replace("/", ":")


def _default_attribute(topic: str) -> str:
    return topic.rstrip("/").rsplit("/", 1)[-1] or "message"


def _tenant(value: Any, where: str) -> str:
    text = _text(value, where + ".service", empty=True).strip().lower()
    if text and not is_stored_tenant(text):
        raise MapError(f"{where}.service {text[:60]!r}: use 1 to 50 letters, digits or underscores")
    return text


def _service_path(value: Any, where: str) -> str:
    path = normalize_service_path(_text(value, where + ".service_path").strip())
    problem = service_path_problem(path)
    if problem is not None:
        raise MapError(f"{where}.service_path {path[:80]!r} {problem}")
    return path


def _text(value: Any, where: str, empty: bool = False) -> str:
    if not isinstance(value, str) or (not value and not empty):
        raise MapError(f"{where} must be a {'' if empty else 'non-empty '}string, not {value!r}"[:200])
    return value


def _keys(data: dict, allowed: set[str], where: str) -> None:
    unknown = sorted(str(k) for k in set(data) - allowed)
    if unknown:
        raise MapError(f"{where}: unknown key {unknown[0]!r} (known: {', '.join(sorted(allowed))})")
