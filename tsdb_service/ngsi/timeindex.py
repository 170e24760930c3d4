"""Which instant a notified entity is stored at, and how NGSI times are read.

Every attribute of an entity in one notification shares one time index, as
in QuantumLeap, so a wide history row can be rebuilt. The index is the first
of these that yields a valid time:

1. the attribute named by the ``Fiware-TimeIndex-Attribute`` header;
2. a ``TimeInstant`` attribute, else the newest ``TimeInstant`` metadata;
3. a ``timestamp`` attribute;
4. the newest NGSI-LD ``observedAt`` among the entity's properties;
5. the entity's NGSI-LD ``modifiedAt``;
6. a ``dateModified`` attribute, else the newest ``dateModified`` metadata;
7. the reception time.

Sources are collected raw while the entity is parsed and only read when
their rule is reached, so a notification with a ``TimeInstant`` attribute
never pays for parsing metadata times.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from datetime import datetime, timedelta, timezone
from typing import Any

UTC = timezone.utc
EPOCH = datetime(1970, 1, 1, tzinfo=UTC)

# Epoch numbers this large are milliseconds: 1e11 s is the year 5138, while
# 1e11 ms is 1973, so the two ranges do not overlap for real data.
_MILLIS_THRESHOLD = 1e11

WATCHED_ATTRIBUTES = frozenset({"TimeInstant", "timestamp", "dateModified"})


def _no_op() -> None:
    pass


# Called once per entity whose time index falls back to the reception time;
# ``tsdb_service.metrics`` installs its counter here (a hook, so this parser
# stays free of metrics code).
on_fallback: Callable[[], None] = _no_op


def parse_time(value: Any) -> datetime | None:
    """A tz-aware UTC datetime from an NGSI time value, or ``None``.

    Strings must be ISO 8601 extended format starting ``YYYY-MM-DD``: that
    shape check is what stops QuantumLeap's bug of reading ``"5"`` as a
    date, and it is cheap enough to run on every inferred string. Numbers are
    epoch seconds (milliseconds when large); numeric strings are not times.
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

    __slots__ = ("header_attr", "watched", "values", "time_instant_md", "date_modified_md", "observed_at", "modified_at")

    def __init__(self, header_attr: str | None, watched: frozenset[str]):
        self.header_attr = header_attr
        self.watched = watched  # attribute names whose values matter here
        self.values: dict[str, Any] = {}
        self.time_instant_md: list[Any] = []
        self.date_modified_md: list[Any] = []
        self.observed_at: list[Any] = []
        self.modified_at: Any = None

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
        for moment in self._candidates():
            if moment is not None:
                return moment
        on_fallback()
        return received_at

    def _candidates(self):
        """The rules of the module docstring, in order, evaluated lazily."""
        values = self.values
        if self.header_attr is not None:
            yield parse_time(values.get(self.header_attr))
        yield parse_time(values.get("TimeInstant"))
        yield _newest(self.time_instant_md)
        yield parse_time(values.get("timestamp"))
        yield _newest(self.observed_at)
        yield parse_time(self.modified_at)
        yield parse_time(values.get("dateModified"))
        yield _newest(self.date_modified_md)


def watched_attributes(header_attr: str | None) -> frozenset[str]:
    """Attribute names to remember for one notification (built once per call)."""
    return WATCHED_ATTRIBUTES | {header_attr} if header_attr else WATCHED_ATTRIBUTES
