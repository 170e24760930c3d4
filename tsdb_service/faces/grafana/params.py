"""What a Grafana request asks for, checked once: scope, entities, columns, time.

Grafana datasources speak in query parameters (Infinity) or JSON bodies
(SimpleJSON); both end up here, so every endpoint validates the same way and
no input can reach the history layer unchecked. Tenant, service path,
entity filter, counts, aggregation and time range follow the rules every API
shares (``parse.request_context``, where their precedence is written down);
this module adds what only Grafana has: columns (aliased value paths) and
its lenient flags and choices. Errors are ``BadRequest``s, rendered in the
NGSI shape by the app's one error handler.
"""

from __future__ import annotations

import re

from tsdb_service.core.errors import BadRequest
from tsdb_service.core.query import AggrMethod, AggrPeriod
from tsdb_service.history.drawing import Column, Fill
from tsdb_service.history.valuepath import parse_value_path
from tsdb_service.parse.request_context import aggr_method, aggr_period, entity_filter, moment
from tsdb_service.parse.request_context import grafana_time_range as time_range
from tsdb_service.parse.request_context import lenient_count as positive_int

__all__ = [
    "MAX_POINTS_LIMIT",
    "Column",
    "aggregate_method",
    "aggregate_period",
    "choice",
    "columns",
    "entity_filter",
    "fill_choice",
    "flag",
    "moment",
    "positive_int",
    "service_url",
    "time_range",
]

_ALIAS = re.compile(r"^[A-Za-z_][A-Za-z0-9_]{0,63}$")
_MAX_COLUMNS = 64
MAX_POINTS_LIMIT = 100_000
RESERVED = frozenset({"time", "entity", "type", "name", "lat", "lon", "timeEnd", "title", "text", "tags"})
# The order Grafana's ``method`` lists them in (avg, the default, first).
_METHODS = (AggrMethod.AVG, AggrMethod.MIN, AggrMethod.MAX, AggrMethod.SUM, AggrMethod.COUNT)


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


def aggregate_method(raw: str | None) -> AggrMethod:
    """``method`` of ``/aggregate``: the history API's vocabulary, avg by
    default; surrounding blanks are forgiven (dashboard variables add them)."""
    return AggrMethod.AVG if raw is None or not raw.strip() else aggr_method(raw.strip(), "method", _METHODS)


def aggregate_period(raw: str | None) -> AggrPeriod | None:
    """``period`` of ``/aggregate``: none (one value per entity) or second ... year."""
    return None if raw is None else aggr_period(raw.strip(), "period")


def flag(raw: str | None, name: str) -> bool:
    if raw is None or raw == "":
        return False
    low = raw.strip().lower()
    if low in ("1", "true", "yes", "on"):
        return True
    if low in ("0", "false", "no", "off"):
        return False
    raise BadRequest(f"{name} must be true or false, not {raw[:40]!r}")


def fill_choice(raw: str | None, name: str = "fill") -> str:
    """``fill``: what an empty bucket shows; none (a gap, the default), null,
    previous or linear."""
    return choice(raw, name, tuple(f.value for f in Fill), "none")


def choice(raw: str | None, name: str, allowed: tuple[str, ...], default: str) -> str:
    if raw is None or raw == "":
        return default
    low = raw.strip().lower()
    if low not in allowed:
        raise BadRequest(f"{name} must be one of {', '.join(allowed)}, not {raw[:40]!r}")
    return low


# Characters a service URL may hold in the provisioning YAML we write it into:
# no quote, space, '#', newline or anything YAML would read as syntax.
_URL_CHARS = frozenset("ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789-._~:/[]%")
_URL_MAX = 200


def service_url(raw: str | None, default: str) -> str:
    """``url``: where Grafana reaches this service, ``http(s)://host[:port][/path]``
    (no user info, query or fragment), without a trailing ``/``; ``default`` when absent."""
    if raw is None or not raw.strip():
        return default
    url = raw.strip().rstrip("/")
    problem = None
    if len(url) > _URL_MAX or not set(url) <= _URL_CHARS:
        problem = f"at most {_URL_MAX} characters of A-Z a-z 0-9 - . _ ~ : / [ ] %"
    else:
        from urllib.parse import urlsplit

        parts = urlsplit(url)
        try:
            port_ok = parts.port is None or parts.port > 0
        except ValueError:
            port_ok = False
        if parts.scheme not in ("http", "https") or not parts.hostname or not port_ok:
            problem = "http(s)://host[:port][/path]"
    if problem:
        raise BadRequest(f"url: {raw[:80]!r} is not a service URL: {problem}")
    return url
