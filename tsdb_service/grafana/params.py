"""What a Grafana request asks for, checked once: scope, entities, columns, time.

Grafana datasources speak in query parameters (Infinity) or JSON bodies
(SimpleJSON); both end up here, so every endpoint validates the same way and
no input can reach the history layer unchecked. Errors are ``BadRequest``s,
rendered in the NGSI shape by the app's one error handler.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from dataclasses import dataclass
from datetime import UTC, datetime

from ..api.tenancy import tenant_from
from ..errors import BadRequest
from ..history.params import MAX_INT_PARAM, check_id, parse_time, service_paths
from ..history.valuepath import parse_value_path
from ..idpattern import compile_pattern
from ..query import EntityFilter, Scope, TimeRange, ValuePath

_ALIAS = re.compile(r"^[A-Za-z_][A-Za-z0-9_]{0,63}$")
_NUMBER = re.compile(r"^-?\d{1,16}(\.\d{1,9})?$")
_MAX_COLUMNS = 64
_MAX_IDS = 1000
MAX_POINTS_LIMIT = 100_000
RESERVED = frozenset({"time", "entity", "type", "name", "lat", "lon", "timeEnd", "title", "text", "tags"})


@dataclass(frozen=True, slots=True)
class Column:
    """One output column: a value path and the name rows carry it under."""

    name: str
    path: ValuePath


def scope_of(params: Mapping[str, str], headers: Mapping[str, str]) -> Scope:
    """Tenant and service paths. The tenant follows the one rule of every
    endpoint (``ngsi.tenancy``), with the ``service`` query parameter as one
    more selector: header and parameter must agree (Infinity datasources
    may send either). ``servicepath`` wins over ``Fiware-ServicePath``."""
    services = params.getlist("service") if hasattr(params, "getlist") else [params.get("service") or ""]
    tenant = tenant_from(headers.items(), [("service", value) for value in services])
    path = params.get("servicepath")
    if path is None:
        path = headers.get("fiware-servicepath")
    return Scope(tenant, service_paths(path))


def entity_filter(params: Mapping[str, str]) -> EntityFilter:
    """``id`` (comma list), ``idPattern`` (regex), ``type`` (comma list)."""
    ids = _names(params.get("id"), "id", _MAX_IDS)
    types = _names(params.get("type"), "type", 100)
    pattern = params.get("idPattern") or None
    if pattern is not None:
        compile_pattern(pattern)  # RE2, linear time: see tsdb_service.idpattern
    return EntityFilter(ids=ids, id_pattern=pattern, types=types)


def _names(raw: str | None, what: str, most: int) -> tuple[str, ...] | None:
    if raw is None:
        return None
    items = tuple(dict.fromkeys(part.strip() for part in raw.split(",") if part.strip()))
    if not items:
        return None
    if len(items) > most:
        raise BadRequest(f"{what} lists at most {most} names")
    for item in items:
        check_id(item, what)  # the ingest's rule for ids and types
    return items


def columns(raw: str | None, *, required: bool = True, what: str = "attrs") -> tuple[Column, ...]:
    """``attrs=speed=odom(twist.twist.linear.x),temperature``: value paths,
    each optionally named ``alias=path`` (``=`` cannot occur in an NGSI
    attribute name or a value path, so the split is unambiguous)."""
    if raw is None or not raw.strip():
        if required:
            raise BadRequest(
                f"{what} is required: a comma list of attributes or value paths, e.g. "
                f"{what}=speed=odom(twist.twist.linear.x),temperature"
            )
        return ()
    out: dict[str, Column] = {}
    for item in (part.strip() for part in raw.split(",")):
        if not item:
            continue
        alias, sep, text = item.partition("=")
        if not sep:
            alias, text = "", item
        path = parse_value_path(text.strip())
        name = alias.strip() or path.text
        if alias and not _ALIAS.match(name):
            raise BadRequest(f"bad column name {alias[:60]!r}: use a letter or _ then letters, digits or _")
        if name in RESERVED:
            raise BadRequest(f"{name!r} is a reserved column name; choose another alias")
        if name in out:
            raise BadRequest(f"column {name!r} is given twice")
        out[name] = Column(name, path)
        if len(out) > _MAX_COLUMNS:
            raise BadRequest(f"{what} lists at most {_MAX_COLUMNS} columns")
    if required and not out:
        raise BadRequest(f"{what} is required")
    return tuple(out.values())


def moment(raw: str | None, name: str) -> datetime | None:
    """Grafana's ``${__from}`` (epoch milliseconds) or an ISO 8601 date-time."""
    if raw is None or not raw.strip():
        return None
    text = raw.strip()
    if _NUMBER.match(text):
        try:
            return datetime.fromtimestamp(float(text) / 1000.0, tz=UTC)
        except (OverflowError, OSError, ValueError):
            raise BadRequest(f"{name} {text[:40]!r} is out of range") from None
    try:
        return parse_time(text, name)
    except BadRequest:
        raise BadRequest(f"{name} must be epoch milliseconds or ISO 8601, not {text[:60]!r}") from None


def time_range(params: Mapping[str, str]) -> TimeRange:
    start = moment(params.get("from"), "from")
    end = moment(params.get("to"), "to")
    if start is not None and end is not None and start > end:
        raise BadRequest("from must not be after to")
    return TimeRange(start, end)


def positive_int(raw: str | None, name: str, default: int | None, most: int) -> int | None:
    """A positive integer up to ``MAX_INT_PARAM`` (the rule of every
    endpoint), then capped at ``most``; Grafana sometimes sends ``1500.0``."""
    if raw is None or not str(raw).strip():
        return default
    text = str(raw).strip()
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not math.isfinite(value) or not 1 <= value <= MAX_INT_PARAM:
        raise BadRequest(f"{name} must be a number from 1 to {MAX_INT_PARAM}, not {text[:40]!r}")
    return min(int(value), most)


def flag(raw: str | None, name: str) -> bool:
    if raw is None or raw == "":
        return False
    low = raw.strip().lower()
    if low in ("1", "true", "yes", "on"):
        return True
    if low in ("0", "false", "no", "off"):
        return False
    raise BadRequest(f"{name} must be true or false, not {raw[:40]!r}")


def choice(raw: str | None, name: str, allowed: tuple[str, ...], default: str) -> str:
    if raw is None or raw == "":
        return default
    low = raw.strip().lower()
    if low not in allowed:
        raise BadRequest(f"{name} must be one of {', '.join(allowed)}, not {raw[:40]!r}")
    return low
