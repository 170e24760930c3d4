"""Which instant a notified entity is stored at, and how NGSI times are read.

Every attribute of an entity in one notification shares one time index, as
in QuantumLeap, so a wide history row can be rebuilt. The index is the first
of these that yields a valid time:

1. the attribute named by the ``Fiware-TimeIndex-Attribute`` header, or the
   stamp at a value path inside it (``odom(header.stamp)``: ``read_stamp``);
2. a ``TimeInstant`` attribute, else the newest ``TimeInstant`` metadata;
3. a ``timestamp`` attribute;
4. the newest NGSI-LD ``observedAt`` among the entity's properties;
5. the entity's NGSI-LD ``modifiedAt``;
6. a ``dateModified`` attribute, else the newest ``dateModified`` metadata;
7. the reception time.

A source that is present but cannot be a time (``0000-01-01``, year 99999,
epoch ``1e20``, a boolean, ``"n/a"``) is skipped like a missing one. When
that leaves the reception time, the fallback is recorded: every attribute
sample of the entity gets the metadata item ``timeIndexFallback`` naming the
unusable sources, and ``on_fallback`` (a Prometheus counter) counts every
entity stored at the reception time.

Epoch numbers: a magnitude below 10^12 is seconds, from 10^12 on
milliseconds. Every instant of the years 1 to 9999 in seconds is below
2.6 * 10^11, so none is read as milliseconds; seconds beyond the year 9999
(up to 10^12) are not a time, rather than a 1970s instant in milliseconds.
Milliseconds are therefore read from 2001-09-09 on (and before 1938-04-24).

Sources are collected raw while the entity is parsed and only read when
their rule is reached, so a notification with a ``TimeInstant`` attribute
never pays for parsing metadata times.

**Stamps** (``read_stamp``): a robot's own time inside a value. ROS 2's
``builtin_interfaces/Time`` ``{"sec", "nanosec"}``, ROS 1's ``{"secs",
"nsecs"}``, Foxglove's ``{"sec", "nsec"}``, or anything ``parse_time``
reads. Nanoseconds are cut to microseconds (what we store). An all-zero
stamp is the unset header of a message nobody stamped: not a time. The
attributes ``TSDB_TIME_INDEX_PATHS`` names (``core.timepaths``) are timed
by their stamp, each on its own (``parse.notification`` splits them off the
entity's row); a stamp that cannot be read leaves the sample at the
entity's time index, and ``on_stamp_fallback`` counts it.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from datetime import UTC, datetime, timedelta
from typing import Any

from tsdb_service.core.valuesteps import extract, steps_text

UTC = UTC
EPOCH = datetime(1970, 1, 1, tzinfo=UTC)

# Epoch numbers this large are milliseconds (see the module docstring): the
# last second of the year 9999 is 253402300799, far below it.
_MILLIS_THRESHOLD = 1e12

# The metadata item that marks a sample stored at the reception time because
# its entity's time sources could not be read.
FALLBACK_METADATA = "timeIndexFallback"

WATCHED_ATTRIBUTES = frozenset({"TimeInstant", "timestamp", "dateModified"})


def _no_op() -> None:
    pass


# Called once per entity whose time index falls back to the reception time;
# ``tsdb_service.telemetry`` installs its counter here (a hook, so this parser
# stays free of metrics code).
on_fallback: Callable[[], None] = _no_op
# Called once per attribute sample whose stamp (``TSDB_TIME_INDEX_PATHS``, or
# the value path of ``Fiware-TimeIndex-Attribute``) could not be read; the
# same kind of hook.
on_stamp_fallback: Callable[[], None] = _no_op

_NANOS_PER_SECOND = 1_000_000_000
# The seconds of 0001-01-01 and of 9999-12-31T23:59:59 since the epoch.
_FIRST_SECOND, _LAST_SECOND = -62135596800, 253402300799
_STAMP_KEYS = (("sec", "nanosec"), ("secs", "nsecs"), ("sec", "nsec"))


def read_stamp(value: Any) -> datetime | None:
    """A robot's stamp (see the module docstring) as a UTC datetime, or None."""
    if type(value) is dict:
        for sec_key, frac_key in _STAMP_KEYS:
            if sec_key in value and frac_key in value:
                return _from_stamp(value[sec_key], value[frac_key])
    return parse_time(value)


def _from_stamp(sec: Any, nanosec: Any) -> datetime | None:
    if type(sec) is not int or type(nanosec) is not int or not 0 <= nanosec < _NANOS_PER_SECOND:
        return None
    if (sec == 0 and nanosec == 0) or not _FIRST_SECOND <= sec <= _LAST_SECOND:
        return None
    return EPOCH + timedelta(seconds=sec, microseconds=nanosec // 1000)


def parse_time(value: Any) -> datetime | None:
    """A tz-aware UTC datetime from an NGSI time value, or ``None``.

    Strings must be ISO 8601 extended format starting ``YYYY-MM-DD``: that
    shape check is what stops QuantumLeap's bug of reading ``"5"`` as a
    date, and it is cheap enough to run on every inferred string. Numbers are
    epoch seconds, or milliseconds from 10^12 on; numeric strings are not times.
    NGSI-LD typed literals (``{"@type": "DateTime", "@value": ...}``) are
    read through their ``@value``.
    """
    kind = type(value)
    if kind is str:
        return _parse_iso(value)
    if kind is int or kind is float:
        return _from_epoch(value)
    if kind is dict:
        literal = value.get("@value")
        return _parse_iso(literal) if type(literal) is str else None
    return None


def to_utc(moment: datetime) -> datetime:
    """Naive datetimes are taken as UTC, as NGSI does for offset-less times."""
    if moment.tzinfo is None:
        return moment.replace(tzinfo=UTC)
    return moment.astimezone(UTC)


def _parse_iso(text: str) -> datetime | None:
    if not _has_date_shape(text):
        return None
    if text[-1] == "z":
        text = text[:-1] + "Z"
    try:
        # Python 3.11 accepts "Z", any offset form, and truncates fractions
        # longer than microseconds, which is exactly the precision we keep.
        return to_utc(datetime.fromisoformat(text))
    except (ValueError, OverflowError):
        return None


def _has_date_shape(text: str) -> bool:
    """``YYYY-MM-DD`` in ASCII digits, optionally followed by a time part."""
    if len(text) < 10 or text[4] != "-" or text[7] != "-":
        return False
    head = text[:10]
    if not head.isascii() or not (head[:4].isdigit() and head[5:7].isdigit() and head[8:].isdigit()):
        return False
    return len(text) == 10 or text[10] in "Tt "


def _from_epoch(number: float) -> datetime | None:
    if not math.isfinite(number):
        return None
    try:
        if abs(number) >= _MILLIS_THRESHOLD:
            return EPOCH + timedelta(milliseconds=number)
        return EPOCH + timedelta(seconds=number)
    except OverflowError:
        return None


def _newest(values: list[Any]) -> datetime | None:
    newest = None
    for value in values:
        moment = parse_time(value)
        if moment is not None and (newest is None or moment > newest):
            newest = moment
    return newest


def _meta_value(item: Any) -> Any:
    """Metadata is ``{"type": .., "value": ..}``; accept a bare value too."""
    return item.get("value") if type(item) is dict else item


class TimeClues:
    """Raw time sources seen while parsing one entity, resolved on demand."""

    __slots__ = (
        "date_modified_md",
        "header_attr",
        "header_steps",
        "modified_at",
        "observed_at",
        "time_instant_md",
        "unusable",
        "values",
        "watched",
    )

    def __init__(self, header_attr: str | None, watched: frozenset[str], header_steps: tuple = ()):
        self.header_attr = header_attr
        self.header_steps = header_steps  # a value path inside it: the stamp there
        self.watched = watched  # attribute names whose values matter here
        self.values: dict[str, Any] = {}
        self.time_instant_md: list[Any] = []
        self.date_modified_md: list[Any] = []
        self.observed_at: list[Any] = []
        self.modified_at: Any = None
        # After ``resolve`` fell back to the reception time: the sources that
        # were present but not a time (empty when there were none).
        self.unusable: tuple[str, ...] = ()

    def note_value(self, name: str, value: Any) -> None:
        if name in self.watched:
            self.values[name] = value

    def note_metadata(self, metadata: dict) -> None:
        instant = metadata.get("TimeInstant")
        if instant is not None:
            self.time_instant_md.append(_meta_value(instant))
        modified = metadata.get("dateModified")
        if modified is not None:
            self.date_modified_md.append(_meta_value(modified))

    def resolve(self, received_at: datetime) -> datetime:
        if self.header_attr is None:  # the usual case first: a TimeInstant attribute that is a time
            moment = parse_time(self.values.get("TimeInstant"))
            if moment is not None:
                return moment
        for n, (_, raw, read) in enumerate(self._candidates()):
            if raw is not None and raw != []:
                moment = read(raw)
                if moment is not None:
                    return moment
                if n == 0 and self.header_steps:
                    on_stamp_fallback()  # the header's stamp is there but not a time
        on_fallback()
        self.unusable = tuple(
            dict.fromkeys(label for label, raw, _ in self._candidates() if raw is not None and raw != [])
        )
        return received_at

    def _candidates(self):
        """The rules of the module docstring, in order: ``(source, raw, reader)``."""
        values = self.values
        if self.header_attr is not None:
            if self.header_steps:
                label, steps = f"{self.header_attr}({steps_text(self.header_steps)})", self.header_steps
                yield label, values.get(self.header_attr), lambda raw: read_stamp(extract(raw, steps))
            else:
                yield self.header_attr, values.get(self.header_attr), parse_time
        yield "TimeInstant", values.get("TimeInstant"), parse_time
        yield "TimeInstant metadata", self.time_instant_md, _newest
        yield "timestamp", values.get("timestamp"), parse_time
        yield "observedAt", self.observed_at, _newest
        yield "modifiedAt", self.modified_at, parse_time
        yield "dateModified", values.get("dateModified"), parse_time
        yield "dateModified metadata", self.date_modified_md, _newest


def watched_attributes(header_attr: str | None) -> frozenset[str]:
    """Attribute names to remember for one notification (built once per call)."""
    return WATCHED_ATTRIBUTES | {header_attr} if header_attr else WATCHED_ATTRIBUTES
