"""The registration that makes an NGSI-LD broker send us its temporal queries.

NGSI-LD lets a context source register with a broker (ETSI GS CIM 009
V1.9.1: the CSourceRegistration data type, clause 5.2.9, created by ``POST
/ngsi-ld/v1/csourceRegistrations``). A broker that implements distributed
operations (clause 4.3.6) then forwards the operations a registration
lists, for the entities it describes, to the registration's ``endpoint``,
and merges what comes back with its own answer. The temporal history
service registers as:

* ``mode: auxiliary`` (an additive registration, clause 4.3.6): it holds
  data about the entities, never the only copy, so it is consulted for
  reads and never written to, and the broker's own answer stays
  authoritative;
* ``operations: ["retrieveTemporal", "queryTemporal"]`` (the names the
  spec gives the two temporal reads): nothing else;
* ``information``: the entity types whose history it keeps;
* ``endpoint``: its base URL, the broker appends ``/ngsi-ld/v1/temporal/...``.

Invariants: ``ensure_registration`` creates at most one registration per
(broker, tenant, endpoint, types): it first lists the broker's
registrations for the tenant and the types, and keeps one that already
sends the same temporal operations to the same endpoint; a broker whose
registrations cannot be listed is not written to (unless ``force``), so
running it twice never registers twice. Redirects are not followed: a
registration goes to the URL the operator named.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import httpx
import orjson

from tsdb_service.broker.listing import list_all

REGISTRATIONS_PATH = "/ngsi-ld/v1/csourceRegistrations"
TEMPORAL_OPERATIONS = ("retrieveTemporal", "queryTemporal")
JSONLD_CONTEXT_REL = "http://www.w3.org/ns/json-ld#context"
_PAGE = 100  # NGSI-LD brokers cap limit, often at 100 or 1000


@dataclass(frozen=True, slots=True)
class Registration:
    """What to register: where the broker sends temporal queries
    (``endpoint``, our base URL as the broker reaches it), for which entity
    types (terms of ``context``, or IRIs), in which tenant (None: the
    default one)."""

    endpoint: str
    types: tuple[str, ...]
    tenant: str | None = None
    context: str | None = None  # the @context the type names are terms of (None: the core one)

    def document(self) -> dict:
        """The CSourceRegistration (clause 5.2.9) to send."""
        return {
            "type": "ContextSourceRegistration",
            "registrationName": "tsdb-service temporal history",
            "description": "The temporal evolution of these entities, kept by tsdb-service",
            "information": [{"entities": [{"type": t} for t in self.types]}],
            "endpoint": self.endpoint,
            "mode": "auxiliary",
            "operations": list(TEMPORAL_OPERATIONS),
        }

    def headers(self) -> dict[str, str]:
        """The tenant, and the @context the type names are terms of."""
        out = {"Accept": "application/json"}
        if self.tenant:
            out["NGSILD-Tenant"] = self.tenant
        if self.context:
            out["Link"] = f'<{self.context}>; rel="{JSONLD_CONTEXT_REL}"; type="application/ld+json"'
        return out


def equivalent(existing: dict, wanted: Registration) -> bool:
    """Does ``existing`` (as a broker lists it) already send the temporal
    operations for ``wanted``'s types to its endpoint, as an auxiliary source?"""
    endpoint = existing.get("endpoint")
    if not isinstance(endpoint, str) or endpoint.rstrip("/") != wanted.endpoint.rstrip("/"):
        return False
    if existing.get("mode", "inclusive") != "auxiliary":
        return False
    operations = existing.get("operations")
    if not isinstance(operations, list) or not set(TEMPORAL_OPERATIONS) <= set(operations):
        return False
    return _types(existing) == set(wanted.types)


def _types(document: dict) -> set[str]:
    information = document.get("information")
    found: set[str] = set()
    for info in information if isinstance(information, list) else ():
        entities = info.get("entities") if isinstance(info, dict) else None
        for item in entities if isinstance(entities, list) else ():
            kind = item.get("type") if isinstance(item, dict) else None
            found.update([kind] if isinstance(kind, str) else kind if isinstance(kind, list) else [])
    return found


def list_registrations(broker: str, wanted: Registration, timeout: float = 10.0) -> tuple[list[dict] | None, str]:
    """The broker's registrations of the tenant for ``wanted``'s types
    (``GET /csourceRegistrations?type=...``, paged: ``broker.listing``):
    ``(registrations, "")``, or ``(None, why)`` when it could not tell."""
    url = broker.rstrip("/") + REGISTRATIONS_PATH
    params = {"type": ",".join(wanted.types), "count": "true"}
    return list_all(url, params, wanted.headers(), "registrations", timeout, page_size=_PAGE)


def post_registration(broker: str, wanted: Registration, timeout: float = 10.0) -> tuple[bool, str]:
    """Create the registration; (created?, what the broker answered)."""
    url = broker.rstrip("/") + REGISTRATIONS_PATH
    headers = {**wanted.headers(), "Content-Type": "application/json"}
    try:
        response = httpx.post(url, content=orjson.dumps(wanted.document()), headers=headers, timeout=timeout)
    except httpx.HTTPError as exc:
        return False, f"could not reach {url}: {type(exc).__name__}: {exc}"
    if response.status_code == 201:
        location = response.headers.get("location", "")
        reg_id = location.rstrip("/").rsplit("/", 1)[-1] or "?"
        return True, f"201 Created: registration {reg_id} ({location}){_in(wanted)}"
    return False, f"{response.status_code} {response.reason_phrase}: {_text(response)}"


def ensure_registration(
    broker: str, wanted: Registration, timeout: float = 10.0, force: bool = False
) -> tuple[bool, str]:
    """Register unless the broker has an equivalent registration for the
    tenant (``force``: register anyway). ``(ok?, what happened)``."""
    if force:
        return post_registration(broker, wanted, timeout)
    existing, problem = list_registrations(broker, wanted, timeout)
    if existing is None:
        hint = "" if problem.startswith("could not reach") else " (--force registers without checking)"
        return False, f"{problem}; nothing registered{hint}"
    same = next((item for item in existing if equivalent(item, wanted)), None)
    if same is None:
        return post_registration(broker, wanted, timeout)
    return True, (
        f"already registered: registration {same.get('id', '?')}{_in(wanted)} sends "
        f"{', '.join(TEMPORAL_OPERATIONS)} for {', '.join(wanted.types)} to {wanted.endpoint}; nothing created "
        "(--force registers another)"
    )


def _in(wanted: Registration) -> str:
    return f" in tenant {wanted.tenant!r}" if wanted.tenant else ""


def _text(response: httpx.Response) -> str:
    return " ".join(response.text.split())[:500]


def check_types(types: Sequence[str]) -> tuple[str, ...]:
    """The entity types to register (a comma list per flag), at least one:
    a registration's ``information`` names what it provides."""
    found = tuple(dict.fromkeys(t.strip() for item in types for t in item.split(",") if t.strip()))
    if not found:
        raise ValueError("--type: name the entity types whose history the broker should ask us for")
    return found
