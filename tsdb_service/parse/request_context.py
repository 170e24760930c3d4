"""The request context, parsed once for every API.

Tenant, service-path scope, entity filter, limits, aggregation and time
range mean the same on every endpoint: notifications (``/v2/notify``,
``/ngsi-ld/v1/notify``), the history routes (``/v2/...``), ``/v2/op/query``,
export, Grafana (``/grafana/...``) and the NGSI-LD temporal API
(``/ngsi-ld/v1/temporal/...``). This module is the only place that reads
them; the API modules only say where each value comes from (a header, a
query parameter, a JSON body) and how their errors look. Everything raises
``BadRequest``, which the app renders in the NGSI shape
``{"error", "description"}`` and, under ``/ngsi-ld/``, as ProblemDetails of
type ``BadRequestData``; the notification parser turns tenant and service
path problems into its ``ParseError`` (the notification is then kept in the
rejected store).

Precedence, what wins and what a missing or empty value means:

=================  ====================================================  ==========================================
value              selectors                                             rule
=================  ====================================================  ==========================================
tenant             ``Fiware-Service``, ``NGSILD-Tenant`` (every API,     every selector that is present and not
                   each header possibly repeated); on Grafana also       blank must name the same tenant, compared
                   ``?service=`` (repeatable)                            stripped and lower-cased. Nothing wins:
                                                                         two different tenants are a 400 (the
                                                                         notification is kept, under the selectors
                                                                         joined by ``,``). A blank selector
                                                                         (``Fiware-Service:``, ``?service=``) is
                                                                         absent; none at all is the default tenant
                                                                         ``""``. A tenant is 1 to 50 ASCII letters,
                                                                         digits or ``_`` (checked before
                                                                         lower-casing), stored lower-cased.
service path,      ``Fiware-ServicePath``                                one path for every entity, or Orion's
notification                                                             comma list of one path per entity (the
                                                                         same count); missing or blank: ``/``.
service path,      ``Fiware-ServicePath``; on Grafana also               a comma list of at most 50 paths, each
query              ``?servicepath=``                                     optionally ending in ``/#`` (the path and
                                                                         below, which is what a path means here
                                                                         anyway); missing, blank, ``/``, ``/#`` or
                                                                         ``#``: the whole tenant. On Grafana a
                                                                         non-blank ``servicepath`` replaces the
                                                                         header: a panel narrows the default scope
                                                                         of its datasource. Unlike a tenant, a path
                                                                         selects within what the caller may read
                                                                         anyway, so choosing one hides nothing.
                                                                         NGSI-LD has no service paths.
entity ids, types  ``id``, ``type`` (comma lists), path segments,        each item trimmed, blanks dropped,
                   ``/v2/op/query``'s ``entities``, NGSI-LD              duplicates dropped; each follows the
                   ``EntitySelector``                                    ingest's rule (``parse.names``); at most
                                                                         ``MAX_IDS`` per list. A list left empty
                                                                         is no filter.
id pattern         ``idPattern`` (every API), SimpleJSON                 RE2 (``tsdb_service.core.idpattern``), at most
                   ``payload.idPattern``                                 512 characters; blank: no pattern.
integers           ``lastN``, ``limit``, ``offset`` (and NGSI-LD         decimal, ``lastN``/``limit`` from 1 (from 0
                   ``firstN``)                                           on NGSI-LD, where ``limit=0&count=true``
                                                                         counts), ``offset`` from 0, at most
                                                                         ``MAX_INT_PARAM`` = 2^53 - 1; blank:
                                                                         absent. The history ``limit`` is then
                                                                         capped at ``TSDB_DEFAULT_LIMIT``.
                   Grafana's ``max_points``, ``limit``,                  a number from 1 to ``MAX_INT_PARAM``
                   ``maxDataPoints``, ``intervalMs``                     (Grafana writes ``1500.0``), capped at
                                                                         the endpoint's maximum.
aggregation        ``aggrMethod``/``aggrPeriod``/``aggrScope``           one vocabulary (``query.AggrMethod``,
                   (history); ``method``/``period`` (Grafana)            ``AggrPeriod``), case-insensitive; blank
                                                                         is absent; a period without a method is
                                                                         a 400. NGSI-LD's ``aggrMethods`` and ISO
                                                                         8601 ``aggrPeriodDuration`` are the
                                                                         spec's own (``ngsild.params``).
time range         ``fromDate``/``toDate`` (history, export),            ISO 8601 with any offset (naive: UTC),
                   ``from``/``to`` (Grafana), ``timeAt``/``endTimeAt``   optionally quoted; Grafana also takes
                   (NGSI-LD)                                             epoch milliseconds. Blank: unbounded.
=================  ====================================================  ==========================================

``MAX_IDS`` is 10,000 for every API. It was 10,000 on the history API and
1,000 on Grafana (and on NGSI-LD ``id`` lists): the larger one, so that no
request that worked before is refused. The cost of an id list is one
in-memory catalog lookup per id, and the read budget
(``TSDB_READ_MAX_SERIES``) bounds what the matched series may cost, so the
list length itself needs only a sanity bound.
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterable, Mapping
from datetime import UTC, datetime
from typing import overload

from tsdb_service.core.errors import BadRequest, ParseError
from tsdb_service.core.idpattern import compile_pattern
from tsdb_service.core.query import Aggregation, AggrMethod, AggrPeriod, AggrScope, EntityFilter, Scope, TimeRange
from tsdb_service.parse.names import (
    ID_RULE,
    SERVICE_PATH_RULE,
    id_problem,
    normalize_service_path,
    service_path_problem,
)

MAX_IDS = 10_000
# The largest integer any parameter may take (limits, offsets, lastN,
# Grafana point counts): 2^53 - 1, exact in every JSON client.
MAX_INT_PARAM = 2**53 - 1
MAX_SERVICE_PATHS = 50

TENANT_HEADERS = ("fiware-service", "ngsild-tenant")
_TENANT = re.compile(r"[A-Za-z0-9_]{1,50}\Z")
_INT = re.compile(r"\+?[0-9]{1,20}\Z")
_NUMBER = re.compile(r"^-?\d{1,16}(\.\d{1,9})?$")

_METHODS = {m.value: m for m in AggrMethod}
_PERIODS = {p.value: p for p in AggrPeriod}
_SCOPES = {s.value: s for s in AggrScope}


# --- tenant -------------------------------------------------------------------------


class TenantProblem(ValueError):
    """The selectors do not name one valid tenant (the message says why)."""


def selectors(headers: Iterable[tuple[str, str]]) -> list[tuple[str, str]]:
    """``(name, raw value)`` of every tenant header, duplicates included,
    blank ones left out. ``headers`` are ``(name, value)`` pairs, as
    ``Mapping.items()`` or Starlette's ``Headers.items()`` (which keeps
    repeated headers) give them."""
    out = []
    for name, value in headers:
        low = name.lower()
        if low in TENANT_HEADERS and value.strip():
            out.append((low, value))
    return out


def select_tenant(chosen: list[tuple[str, str]]) -> str:
    """The one tenant the selectors name, lower-cased; ``""`` without any.
    Pure: raises ``TenantProblem``, which each caller words its own way."""
    if not chosen:
        return ""
    names = {raw.strip().lower() for _, raw in chosen}
    if len(names) > 1:
        listed = ", ".join(f"{name} {raw.strip()[:60]!r}" for name, raw in chosen)
        raise TenantProblem(f"conflicting tenant selectors ({listed}): name one tenant, or the same one in each")
    raw = chosen[0][1].strip()
    if not _TENANT.match(raw):
        raise TenantProblem(f"invalid tenant {raw[:60]!r}: use 1 to 50 letters, digits or underscores")
    return raw.lower()


def is_stored_tenant(name: str) -> bool:
    """Is ``name`` a tenant as the API stores it (``""`` or 1 to 50
    lower-case letters, digits, underscores)? A refused notification is kept
    under the header as received, which is not one."""
    return name == "" or (_TENANT.match(name) is not None and name == name.lower())


def raw_tenant(chosen: list[tuple[str, str]]) -> str:
    """The tenant as received, for keeping a refused notification: the
    selectors' values joined by ``,`` when they conflict. ``,`` is never in
    a valid tenant, so such a record shows only in the operator listing."""
    return ",".join(dict.fromkeys(raw.strip() for _, raw in chosen))


def tenant(headers: Iterable[tuple[str, str]], extra: Iterable[tuple[str, str]] = ()) -> str:
    """The tenant of ``(name, value)`` header pairs plus ``extra`` selectors
    (Grafana's ``service`` parameters), or a 400."""
    chosen = selectors(headers) + [(name, value) for name, value in extra if value.strip()]
    try:
        return select_tenant(chosen)
    except TenantProblem as exc:
        raise BadRequest(f"bad tenant: {exc}", error="BadRequest") from None


HINT_TENANTS = 20  # tenants a hint names at most


def tenant_hint(with_data: Iterable[str], asked: str) -> str | None:
    """For an answer with nothing in it: when the tenant ``asked`` holds no
    series but others do, a sentence naming them (a new user's data is
    usually under the tenant its broker used, e.g. the demo's ``lawnmower``);
    else None."""
    tenants = list(with_data)
    others = [t for t in tenants if t != asked]
    if asked in tenants or not others:
        return None
    who = "the default tenant (no Fiware-Service)" if asked == "" else f"tenant {asked!r}"
    names = ", ".join(t or "(default)" for t in others[:HINT_TENANTS]) + (", ..." if len(others) > HINT_TENANTS else "")
    return f"{who} holds no data; tenants with data: {names}"


def notification_tenant(headers: Iterable[tuple[str, str]]) -> str:
    """``tenant`` for a notification: a ``ParseError`` (kept in the rejected store)."""
    try:
        return select_tenant(selectors(headers))
    except TenantProblem as exc:
        raise ParseError(str(exc)) from None


# --- service paths ------------------------------------------------------------------


def service_paths(header: str | None) -> tuple[str, ...]:
    """A query's ``Fiware-ServicePath``: the paths it reads, ``("/",)`` for
    the whole tenant (see the table above)."""
    if header is None or not header.strip():
        return ("/",)
    parts = [part.strip() for part in header.split(",")]
    if len(parts) > MAX_SERVICE_PATHS:
        raise BadRequest(f"Fiware-ServicePath lists more than {MAX_SERVICE_PATHS} paths")
    out: list[str] = []
    for part in parts:
        path = part
        if path.endswith("/#"):
            path = path[:-2] or "/"
        elif path == "#":
            path = "/"
        path = normalize_service_path(path)
        problem = service_path_problem(path)
        if problem is not None:
            raise BadRequest(f"bad Fiware-ServicePath {part[:80]!r}: {problem} ({SERVICE_PATH_RULE})")
        if path not in out:
            out.append(path)
    return ("/",) if "/" in out else tuple(out)


def notification_service_paths(header: str | None, count: int) -> list[str]:
    """A notification's ``Fiware-ServicePath``: one path per entity (Orion
    sends one for all, or one per entity, comma-separated)."""
    if header is None or not header.strip():
        return ["/"] * count
    paths = [_stored_service_path(part.strip()) for part in header.split(",")]
    if len(paths) == 1:
        return paths * count
    if len(paths) == count:
        return paths
    raise ParseError(f"Fiware-ServicePath lists {len(paths)} paths for {count} entities")


def _stored_service_path(path: str) -> str:
    path = normalize_service_path(path)
    problem = service_path_problem(path)
    if problem is not None:
        raise ParseError(
            f"service path {path[:60]!r} {problem}; we store only paths every query can name: {SERVICE_PATH_RULE}"
        )
    return path


def scope(headers: Mapping[str, str], tenant_name: str) -> Scope:
    """A /v2 query's scope: ``tenant_name`` (already parsed) and ``Fiware-ServicePath``."""
    return Scope(tenant_name, service_paths(headers.get("fiware-servicepath")))


def grafana_scope(params: Mapping[str, str], headers: Mapping[str, str]) -> Scope:
    """A Grafana request's scope: the tenant headers plus every ``service``
    parameter must agree; a non-blank ``servicepath`` replaces the header."""
    services = params.getlist("service") if hasattr(params, "getlist") else [params.get("service") or ""]
    name = tenant(headers.items(), [("service", value) for value in services])
    path = params.get("servicepath")
    if path is None or not path.strip():
        path = headers.get("fiware-servicepath")
    return Scope(name, service_paths(path))


# --- entities -----------------------------------------------------------------------


def check_id(value: str, name: str) -> None:
    """An entity id or type as the ingest accepts them (``parse.names``)."""
    problem = id_problem(value)
    if problem is not None:
        raise BadRequest(f"{name} {value[:80]!r} {problem}: {ID_RULE}")


def id_list(raw: str | None, name: str) -> tuple[str, ...] | None:
    """A comma list of entity ids or types (``id=``, ``type=``): None when
    absent or empty, at most ``MAX_IDS`` items, each following the rule."""
    if raw is None:
        return None
    items = tuple(dict.fromkeys(part.strip() for part in raw.split(",") if part.strip()))
    if len(items) > MAX_IDS:
        raise BadRequest(f"{name} lists at most {MAX_IDS} entity {'ids' if name == 'id' else 'types'}")
    for item in items:
        check_id(item, name)
    return items or None


def id_pattern(raw: str | None, name: str = "idPattern") -> str | None:
    """``idPattern``, validated (RE2, linear time: see ``tsdb_service.core.idpattern``)."""
    if raw is None or not raw:
        return None
    compile_pattern(raw, name)
    return raw


def entity_filter(params: Mapping[str, str]) -> EntityFilter:
    """``id``, ``idPattern`` and ``type`` of a query string."""
    get = params.get
    return EntityFilter(
        ids=id_list(get("id"), "id"), id_pattern=id_pattern(get("idPattern")), types=id_list(get("type"), "type")
    )


# --- limits -------------------------------------------------------------------------


def int_param(raw: str | None, name: str, low: int) -> int | None:
    """A decimal integer from ``low`` to ``MAX_INT_PARAM``, or None when absent.

    The one integer rule of every endpoint: the bound keeps any value far
    inside what both databases (64-bit) and JSON clients (53-bit) can hold,
    so no integer a client sends can fail anywhere past this check."""
    if raw is None or raw == "":
        return None
    text = raw.strip()
    kind = "a positive" if low == 1 else "a non-negative" if low == 0 else f"an integer from {low}, as"
    if not _INT.match(text) or int(text) < low:
        raise BadRequest(f"{name} must be {kind} integer, not {raw[:40]!r}")
    if int(text) > MAX_INT_PARAM:
        raise BadRequest(f"{name} must be {kind} integer up to {MAX_INT_PARAM}, not {raw[:40]!r}")
    return int(text)


def positive(raw: str | None, name: str) -> int | None:
    return int_param(raw, name, 1)


def non_negative(raw: str | None, name: str) -> int | None:
    return int_param(raw, name, 0)


def page_limit(raw: str | None, default_limit: int) -> int:
    """A history ``limit``: positive, capped at ``default_limit`` (which it defaults to)."""
    limit = positive(raw, "limit")
    return default_limit if limit is None else min(limit, default_limit)


@overload
def lenient_count(raw: str | None, name: str, default: int, most: int) -> int: ...
@overload
def lenient_count(raw: str | None, name: str, default: None, most: int) -> int | None: ...
def lenient_count(raw: str | None, name: str, default: int | None, most: int) -> int | None:
    """A positive number up to ``MAX_INT_PARAM`` (the integer rule), then
    capped at ``most``; Grafana sometimes sends ``1500.0``."""
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


# --- aggregation --------------------------------------------------------------------


def aggr_method(raw: str, name: str = "aggrMethod", allowed: Iterable[AggrMethod] = AggrMethod) -> AggrMethod:
    """One of ``allowed`` (case-insensitive, exact: ``"AVG "`` is refused)."""
    choices = {m.value: m for m in allowed}
    method = choices.get(raw.lower())
    if method is None:
        raise BadRequest(f"{name} must be one of {', '.join(choices)}, not {raw[:40]!r}")
    return method


def aggr_period(raw: str | None, name: str = "aggrPeriod") -> AggrPeriod | None:
    """``year`` ... ``second`` (case-insensitive); absent or empty is none."""
    if raw is None or raw == "":
        return None
    period = _PERIODS.get(raw.lower())
    if period is None:
        raise BadRequest(f"{name} must be one of {', '.join(_PERIODS)}, not {raw[:40]!r}")
    return period


def aggregation(method: str | None, period: str | None, scope_raw: str | None) -> Aggregation | None:
    """The history API's ``aggrMethod``, ``aggrPeriod`` and ``aggrScope``."""
    if method is None or method == "":
        if period not in (None, ""):
            raise BadRequest("aggrMethod is compulsory when using aggrPeriod.", error="Bad parameters use")
        if scope_raw not in (None, "", "entity", "global"):
            raise BadRequest(f"aggrScope must be one of entity, global, not {scope_raw[:40]!r}")
        return None
    chosen = aggr_method(method)
    p = aggr_period(period)
    s = AggrScope.ENTITY
    if scope_raw not in (None, ""):
        found = _SCOPES.get(scope_raw.lower())
        if found is None:
            raise BadRequest(f"aggrScope must be one of {', '.join(_SCOPES)}, not {scope_raw[:40]!r}")
        s = found
    return Aggregation(chosen, p, s)


# --- time ---------------------------------------------------------------------------


def parse_time(raw: str, name: str) -> datetime:
    """ISO 8601 with any offset (naive means UTC), optionally quoted."""
    text = raw.strip().strip('"').strip()
    try:
        if len(text) > 64:
            raise ValueError("too long")
        moment = datetime.fromisoformat(text)
    except ValueError:
        raise BadRequest(
            f"{name} must be an ISO 8601 date-time such as 2024-05-01T10:00:00Z, not {raw[:80]!r}"
        ) from None
    if moment.tzinfo is None:
        return moment.replace(tzinfo=UTC)
    try:
        return moment.astimezone(UTC)
    except (OverflowError, ValueError):
        raise BadRequest(f"{name} {raw[:80]!r} is out of range") from None


def time_range(from_raw: str | None, to_raw: str | None) -> TimeRange:
    """``fromDate`` / ``toDate`` (inclusive bounds; blank is unbounded)."""
    start = parse_time(from_raw, "fromDate") if from_raw not in (None, "") else None
    end = parse_time(to_raw, "toDate") if to_raw not in (None, "") else None
    return TimeRange(start, end)


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


def grafana_time_range(params: Mapping[str, str]) -> TimeRange:
    """Grafana's ``from`` / ``to``."""
    start = moment(params.get("from"), "from")
    end = moment(params.get("to"), "to")
    if start is not None and end is not None and start > end:
        raise BadRequest("from must not be after to")
    return TimeRange(start, end)
