"""A robot's recording, read without ROS: ROS 2 bags, ROS 1 bags, JSON MCAP files.

What can be opened (``Recording.open``):

* a rosbag2 directory (``metadata.yaml`` and its ``.db3`` or ``.mcap``
  files), or one of those storage files on its own, and a ROS 1 ``.bag``,
  through ``rosbags`` (pure Python): messages are CDR (ROS 2) or ROS 1
  serialised, and **their definitions come from the bag itself**, so custom
  messages work. A type whose definition the bag lacks (rosbag2 sqlite3
  bags before Iron store none) is taken from rosbags' standard types of the
  bag's distribution when it is one of them; otherwise it is an error, if
  (and only if) the import reads that topic;
* an MCAP file whose channels are JSON (what ``tsdb-service export --format
  mcap`` writes, and what Foxglove records from JSON sources), through the
  ``mcap`` reader: each message is already the JSON value. A channel in
  another encoding (Protobuf, CBOR) is a topic of unknown type: an error
  if (and only if) the import reads it.

Invariants:

* **One order, from the content alone.** Messages come by receive time,
  then topic, then bytes (``ordered``), so a bag and its conversion to the
  other storage give the same sequence, and an import resumes by counting
  messages into it.
* **Damage is found before anything is written.** ``check`` reads every
  selected message once (raw, no decoding), counts it against what the
  bag's index says, and digests the sequence (BLAKE2b-128 over topic, time,
  length and bytes: the recording's identity for the import's bookkeeping).
  Any failure of the storage (a truncated file, a bad chunk, a malformed
  SQLite page) is ``BagError``, one line.
* Nothing here writes; a ``Recording`` is used from one thread.
"""

from __future__ import annotations

import hashlib
import struct
from collections.abc import Callable, Iterable, Iterator
from contextlib import ExitStack
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import orjson

# rosbags' distributions by the names rosbag2's metadata gives them.
_DISTROS = ("dashing", "eloquent", "foxy", "galactic", "humble", "iron", "jazzy", "kilted", "lyrical")
_MCAP_MAGIC = b"\x89MCAP0\r\n"

CDR, ROS1, JSON = "cdr", "ros1", "json"


class BagError(RuntimeError):
    """The recording cannot be read (as a whole); the message is one line."""


class MessageUnreadable(ValueError):
    """One message cannot be decoded (its bytes do not fit its type)."""


@dataclass(frozen=True, slots=True)
class Topic:
    """A topic of the recording: its message type and how many messages it holds."""

    name: str
    msgtype: str  # "nav_msgs/msg/Odometry"; a JSON channel's schema name ("" without one)
    count: int
    encoding: str  # CDR, ROS1 or JSON
    metadata: dict[str, str] = field(default_factory=dict)  # an MCAP channel's metadata
    known: bool = True  # its definition is known (from the bag or the standard types)


@dataclass(frozen=True, slots=True)
class RawMessage:
    topic: str
    time_ns: int  # the receive (log) time the recording gives it
    data: bytes
    ngsi_type: str | None = None  # an exported MCAP channel's own (its samples' NGSI type)


@dataclass(frozen=True, slots=True)
class CheckedSelection:
    """What ``check`` found: messages per topic and the sequence's digest."""

    counts: dict[str, int]
    digest: bytes  # 16 bytes

    @property
    def total(self) -> int:
        return sum(self.counts.values())


class Recording:
    """An opened recording (a context manager): ``topics``, ``fields``,
    ``check``, ``messages`` and ``decode``."""

    def __init__(self, path: Path, kind: str, stack: ExitStack):
        self.path, self.kind, self._stack = path, kind, stack
        self.topics: dict[str, Topic] = {}
        self._raw: Callable[[set[str]], Iterable[tuple[str, int, bytes, str | None]]] = lambda _: ()
        self._typestore: Any = None
        self._plain: dict[str, list[tuple[str, int]]] = {}

    # --- opening ---------------------------------------------------------------

    @classmethod
    def open(cls, path: str | Path) -> Recording:
        where = Path(path)
        if not where.exists():
            raise BagError(f"no bag at {where}")
        stack = ExitStack()
        try:
            if where.is_file() and where.suffix == ".mcap" and _mcap_profile(where) != "ros2":
                recording = cls(where, "mcap (JSON)", stack)
                recording._open_json_mcap()
            elif where.is_file() and where.suffix == ".bag":
                recording = cls(where, "ROS 1 bag", stack)
                recording._open_ros1()
            else:
                recording = cls(where, "ROS 2 bag", stack)
                recording._open_ros2()
        except BagError:
            stack.close()
            raise
        except Exception as exc:  # rosbags, SQLite, mcap: each library's own errors
            stack.close()
            raise BagError(f"cannot open the bag at {where}: {_reason(exc)}") from None
        return recording

    def __enter__(self) -> Recording:
        return self

    def __exit__(self, *exc_info) -> None:
        self.close()

    def close(self) -> None:
        self._stack.close()

    def _open_ros2(self) -> None:
        from rosbags.rosbag2 import Reader

        if self.path.is_dir() and not (self.path / "metadata.yaml").exists():
            raise BagError(
                f"{self.path} is a directory without metadata.yaml: give a rosbag2 directory, "
                "a .db3 or .mcap file, or a ROS 1 .bag"
            )
        reader = Reader(self.path)
        reader.open()
        self._stack.callback(reader.close)
        distro = (reader.ros_distro or "").lower()
        self._typestore = _typestore(reader.connections, distro if distro in _DISTROS else None)
        self._index(reader.connections, CDR)
        self._raw = lambda names: _from_rosbags(reader, names)

    def _open_ros1(self) -> None:
        from rosbags.rosbag1 import Reader

        reader = Reader(self.path)
        reader.open()
        self._stack.callback(reader.close)
        self._typestore = _typestore(reader.connections, "noetic")
        self._index(reader.connections, ROS1)
        self._raw = lambda names: _from_rosbags(reader, names)

    def _index(self, connections, encoding: str) -> None:
        known = self._typestore.fielddefs
        by_topic: dict[str, list] = {}
        for connection in connections:
            by_topic.setdefault(connection.topic, []).append(connection)
        for name, group in sorted(by_topic.items()):
            types = {c.msgtype for c in group}
            if len(types) > 1:
                raise BagError(f"topic {name} carries several message types ({', '.join(sorted(types))})")
            msgtype = types.pop()
            count = sum(c.msgcount for c in group)
            self.topics[name] = Topic(name, msgtype, count, encoding, known=msgtype in known)

    def _open_json_mcap(self) -> None:
        from mcap.reader import make_reader

        stream = self._stack.enter_context(self.path.open("rb"))
        reader = make_reader(stream)
        summary = reader.get_summary()
        if summary is None:
            raise BagError(f"{self.path} has no summary (an MCAP file cut short?): it cannot be indexed")
        counts = summary.statistics.channel_message_counts if summary.statistics else {}
        for channel in sorted(summary.channels.values(), key=lambda c: c.id):
            schema = summary.schemas.get(channel.schema_id)
            count = counts.get(channel.id, 0)
            if channel.message_encoding != JSON:  # protobuf, CBOR...: unreadable, an error if (only if) imported
                encoding = channel.message_encoding or "unknown"
                self.topics[channel.topic] = Topic(
                    channel.topic, schema.name if schema else "", count, encoding, known=False
                )
                continue
            first = self.topics.get(channel.topic)
            if first is None:
                first = Topic(channel.topic, schema.name if schema else "", 0, JSON, dict(channel.metadata))
            # One topic may have several channels (an attribute whose samples changed shape).
            self.topics[channel.topic] = Topic(first.name, first.msgtype, first.count + count, JSON, first.metadata)
        self._raw = lambda names: _from_mcap(reader, names)

    # --- what the map needs to know ----------------------------------------------

    def fields(self, msgtype: str) -> list[tuple[str, tuple]] | None:
        """The fields of a ROS message type as rosbags describes them
        (``(name, (node type, detail))``), or None (JSON, or unknown)."""
        if self._typestore is None or msgtype not in self._typestore.fielddefs:
            return None
        return list(self._typestore.fielddefs[msgtype][1])

    # --- reading ---------------------------------------------------------------

    def check(self, names: set[str]) -> CheckedSelection:
        """Read every message of ``names`` once, raw: counts and digest, or
        ``BagError`` if the storage is damaged or holds fewer than its index says."""
        digest = hashlib.blake2b(digest_size=16)
        counts = dict.fromkeys(sorted(names), 0)
        head = struct.Struct("<qI")
        try:
            for message in self.messages(names):
                counts[message.topic] += 1
                digest.update(message.topic.encode())
                digest.update(head.pack(message.time_ns, len(message.data)))
                digest.update(message.data)
        except BagError:
            raise
        except Exception as exc:
            done = sum(counts.values())
            raise BagError(f"the bag at {self.path} is damaged after {done} messages: {_reason(exc)}") from None
        short = [n for n in counts if counts[n] < self.topics[n].count]
        if short:
            name = short[0]
            raise BagError(
                f"the bag at {self.path} is truncated: topic {name} holds {counts[name]} messages, "
                f"its index says {self.topics[name].count}"
            )
        return CheckedSelection(counts, digest.digest())

    def messages(self, names: set[str]) -> Iterator[RawMessage]:
        """The messages of ``names`` in the recording's one order (module docstring)."""
        return ordered(self._raw(names))

    def decode(self, message: RawMessage) -> Any:
        """The message as JSON data (``dict``), as the ROS 2 IoT Agent forwards
        it: ROS field order, arrays as lists, time as ``{"sec", "nanosec"}``;
        ``MessageUnreadable`` when its bytes do not fit its type."""
        topic = self.topics[message.topic]
        try:
            if topic.encoding == JSON:
                return orjson.loads(message.data)
            if topic.encoding == CDR:
                obj = self._typestore.deserialize_cdr(message.data, topic.msgtype)
            else:
                obj = self._typestore.deserialize_ros1(message.data, topic.msgtype)
        except Exception as exc:  # serde errors of every kind, struct errors, bad UTF-8
            raise MessageUnreadable(f"{topic.msgtype} on {topic.name}: {_reason(exc)}") from None
        return self._to_plain(obj)

    def _to_plain(self, obj: Any) -> dict:
        spec = self._plain.get(obj.__msgtype__)
        if spec is None:
            spec = self._plain[obj.__msgtype__] = _plain_spec(self._typestore.fielddefs[obj.__msgtype__][1])
        out: dict[str, Any] = {}
        for name, how in spec:
            value = getattr(obj, name)
            if how == _AS_IS:
                out[name] = value
            elif how == _MESSAGE:
                out[name] = self._to_plain(value)
            elif how == _VALUES:
                out[name] = value.tolist() if hasattr(value, "tolist") else list(value)
            else:
                out[name] = [self._to_plain(item) for item in value]
        return out


_AS_IS, _MESSAGE, _VALUES, _MESSAGES = 0, 1, 2, 3


def _plain_spec(fields) -> list[tuple[str, int]]:
    """How to turn each field into JSON data: as is, a message, an array of
    values (numpy arrays for numbers), or an array of messages."""
    from rosbags.typesys.store import Nodetype

    spec = []
    for name, (node, detail) in fields:
        if node == Nodetype.BASE:
            spec.append((name, _AS_IS))
        elif node == Nodetype.NAME:
            spec.append((name, _MESSAGE))
        else:
            sub_node = detail[0][0]
            spec.append((name, _MESSAGES if sub_node == Nodetype.NAME else _VALUES))
    return spec


def ordered(raw: Iterable[tuple[str, int, bytes, str | None]]) -> Iterator[RawMessage]:
    """Messages by time as the reader gives them, those of one instant sorted
    by (topic, bytes): the order depends on the content only."""
    group: list[tuple[int, str, bytes, str]] = []
    current = None
    for topic, time_ns, data, ngsi_type in raw:
        if time_ns != current:
            if group:
                yield from _flush(group)
            group, current = [], time_ns
        group.append((time_ns, topic, bytes(data), ngsi_type or ""))
    if group:
        yield from _flush(group)


def _flush(group: list[tuple[int, str, bytes, str]]) -> Iterator[RawMessage]:
    if len(group) > 1:
        group.sort()
    for time_ns, topic, data, ngsi_type in group:
        yield RawMessage(topic, time_ns, data, ngsi_type or None)


def _from_rosbags(reader, names: set[str]) -> Iterator[tuple[str, int, bytes, None]]:
    connections = [c for c in reader.connections if c.topic in names]
    if not connections:
        return
    for connection, time_ns, data in reader.messages(connections=connections):
        yield connection.topic, time_ns, data, None


def _from_mcap(reader, names: set[str]) -> Iterator[tuple[str, int, bytes, str | None]]:
    if not names:
        return
    for _, channel, message in reader.iter_messages(topics=sorted(names), log_time_order=True):
        yield channel.topic, message.log_time, message.data, channel.metadata.get("tsdb.ngsi_type")


def _typestore(connections, distro: str | None):
    """A typestore of the bag's own definitions, with rosbags' standard types
    of ``distro`` (or the latest) for the types the bag defines nowhere."""
    from rosbags.interfaces import MessageDefinitionFormat
    from rosbags.typesys import Stores, get_types_from_idl, get_types_from_msg, get_typestore

    types: dict = {}
    missing = set()
    for connection in connections:
        definition = connection.msgdef
        if definition.format == MessageDefinitionFormat.MSG and definition.data:
            types.update(get_types_from_msg(definition.data, connection.msgtype))
        elif definition.format == MessageDefinitionFormat.IDL and definition.data:
            types.update(_idl_types(definition.data, get_types_from_idl))
        else:
            missing.add(connection.msgtype)
    store = get_typestore(Stores.EMPTY)
    if missing - set(types):
        name = f"ROS2_{distro.upper()}" if distro and distro != "noetic" else "ROS1_NOETIC" if distro else "LATEST"
        standard = get_typestore(getattr(Stores, name, Stores.LATEST))
        store.register({k: v for k, v in standard.fielddefs.items() if k not in types})
    store.register(types)
    return store


def _idl_types(data: str, parse) -> dict:
    separator = "=" * 80 + "\n"
    if not data.startswith(f"{separator}IDL: "):
        return parse(data)
    types: dict = {}
    for part in data.split(separator)[1:]:
        types.update(parse(part.split("\n", 1)[1]))
    return types


def _mcap_profile(path: Path) -> str | None:
    """The profile an MCAP file's header names (``ros2`` for a rosbag2 file),
    or None when it does not start like an MCAP file."""
    with open(path, "rb") as stream:
        head = stream.read(8 + 1 + 8 + 4 + 64)
    if not head.startswith(_MCAP_MAGIC) or len(head) < 21 or head[8] != 0x01:
        return None
    (length,) = struct.unpack_from("<I", head, 17)
    return head[21 : 21 + length].decode("utf-8", "replace")


def _reason(exc: BaseException) -> str:
    text = " ".join(str(exc).split()) or type(exc).__name__
    return text[:300]
