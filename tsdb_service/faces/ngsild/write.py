"""NGSI-LD temporal writes (ETSI GS CIM 009 clauses 5.6.11-5.6.15, 6.18-6.22).

* ``POST /temporal/entities``: create or add to an entity's temporal
  representation (``201`` + ``Location`` when the entity had no instances,
  else ``204``);
* ``POST /temporal/entities/{id}/attrs``: add instances (``404`` for an
  unknown entity);
* ``DELETE /temporal/entities/{id}``: every instance of the entity;
* ``DELETE /temporal/entities/{id}/attrs/{attrId}``: the default instances
  of the attribute, those of one ``datasetId``, or with ``deleteAll=true``
  all of them;
* ``PATCH`` / ``DELETE /temporal/entities/{id}/attrs/{attrId}/{instanceId}``:
  replace or delete one instance.

The written data is the notified data: each instance becomes a sample read
exactly as a notified NGSI-LD attribute (``parse.notification``), so the
NGSIv2/QuantumLeap API and Grafana see it too (instances with one
observedAt share one NGSIv2 row; one without observedAt gets the time it
was written). ``createdAt`` and ``modifiedAt`` of written instances are
the time of the write; a ``PATCH`` sets ``modifiedAt``; an ``instanceId``
the client gives is kept. Every write goes through the group committer and
is answered after its commit.

Names: the write's ``@context`` (the body's for ``application/ld+json``,
the ``Link`` header's for ``application/json``) says what an attribute
name or type means. A name the core context alone reads the same way is
stored as sent (``speed``, ``Vehicle``: what the NGSIv2 API shows); one
the write's context maps elsewhere is stored as its IRI
(``https://example.org/ns#speed``), so a reader with that context gets
the term back and a reader without it the IRI, as the spec wants. In a
URL, an attribute name is read with the request's ``Link`` context.

Ids and names in a URL are checked before anything is looked up: an
entity id or instanceId that is no URI, or an attribute name no endpoint
could store (empty, a dot segment, ``(``...), is a 400 BadRequestData,
not a 404.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from functools import partial
from typing import Any
from urllib.parse import quote

import orjson
from fastapi import APIRouter, Request
from fastapi.responses import Response
from starlette.concurrency import run_in_threadpool
from starlette.convertors import Convertor, register_url_convertor

from tsdb_service.core.errors import (
    BadRequestData,
    InvalidRequest,
    NonexistentTenant,
    ParseError,
    ResourceNotFound,
    UnsupportedMediaType,
)
from tsdb_service.core.model import INSTANCE_URN_PREFIX, AttrSample, EntitySample, client_instance_id
from tsdb_service.core.query import EntityFilter, Scope, SeriesRef
from tsdb_service.faces.ngsild import openapi as ld_oa
from tsdb_service.faces.ngsild.context import TermMap, link_context
from tsdb_service.faces.ngsild.params import attribute_name, uri
from tsdb_service.faces.ngsild.routes_read import contexts
from tsdb_service.faces.ngsild.scope import scopes
from tsdb_service.http.store import store_of
from tsdb_service.http.tenancy import caller_of, tenant_echo, tenant_of
from tsdb_service.parse.notification import parse_ld_instance
from tsdb_service.parse.text import nul_problem
from tsdb_service.read.requests import InstanceLookup, SeriesSelect
from tsdb_service.write.ops import AppendSamples, DeleteInstance, DeleteSamples, ReplaceInstance


class _Segment(Convertor[str]):
    """A path segment that may be empty (``/entities//attrs``), so an empty
    id or name reaches the route and gets its 400 rather than a 404."""

    regex = "[^/]*"

    def convert(self, value: str) -> str:
        return value

    def to_string(self, value: str) -> str:
        return value


register_url_convertor("segment", _Segment())

router = APIRouter(prefix="/ngsi-ld/v1", tags=["NGSI-LD temporal"])

BASE = "/ngsi-ld/v1/temporal/entities"
_ENTITY_KEYS = frozenset({"id", "type", "@context", "scope", "createdAt", "modifiedAt", "deletedAt"})
_JSON_TYPES = ("application/json", "application/ld+json")
# What a broker or a client writes may be as large as a notification (TSDB_MAX_BODY_BYTES).
LARGE_BODIES = (("POST", BASE), ("PATCH", BASE))


# --- routes ---------------------------------------------------------------------


@router.post(
    "/temporal/entities",
    status_code=201,
    summary="Create or update a temporal representation",
    **ld_oa.ld_spec(ok_codes={201: "Created", 204: "Updated"}, body=ld_oa.LD_ENTITY_BODY),
)
async def upsert_temporal(request: Request) -> Response:
    tenant = tenant_of(request)
    doc, names = await _document(request)
    entity_id = uri(doc.get("id"), "the entity id")
    types = tuple(names.stored(t) for t in _types(doc.get("type")))
    attrs = names.attributes(doc)
    look = partial(_entity_series, request, tenant, entity_id, True)
    existing = await store_of(request).read(look, memory_first=False)
    entity_type = _entity_type(existing, types, entity_id)
    samples = _samples(tenant, entity_id, entity_type, attrs, datetime.now(UTC))
    if samples:
        await store_of(request).write(AppendSamples(samples, dedup=False))
    headers = tenant_echo(request)
    if existing:
        return Response(status_code=204, headers=headers)
    if not samples:
        raise BadRequestData(f"entity {entity_id[:200]!r} has no attribute instances to store")
    return Response(status_code=201, headers={**headers, "Location": f"{BASE}/{quote(entity_id, safe=':')}"})


@router.post(
    "/temporal/entities/{entity_id:segment}/attrs",
    status_code=204,
    summary="Add attribute instances",
    **ld_oa.ld_spec(ok_codes={204: "Added"}, body=ld_oa.LD_FRAGMENT_BODY),
)
async def append_temporal(entity_id: str, request: Request) -> Response:
    tenant = tenant_of(request)
    doc, names = await _document(request)
    existing = await _existing(request, tenant, entity_id)
    body_id = doc.get("id")
    if body_id is not None and body_id != entity_id:
        raise BadRequestData(f"the body's id {str(body_id)[:200]!r} is not the entity of the URL")
    attrs = names.attributes(doc)
    if not attrs:
        raise BadRequestData("the body names no attribute")
    types = tuple(names.stored(t) for t in _types(doc["type"])) if "type" in doc else ()
    entity_type = _entity_type(existing, types, entity_id)
    samples = _samples(tenant, entity_id, entity_type, attrs, datetime.now(UTC))
    if samples:
        await store_of(request).write(AppendSamples(samples, dedup=False))
    return Response(status_code=204, headers=tenant_echo(request))


@router.delete(
    "/temporal/entities/{entity_id}",
    status_code=204,
    summary="Delete a temporal representation",
    **ld_oa.ld_spec(ok_codes={204: "Deleted"}),
)
async def delete_temporal(entity_id: str, request: Request) -> Response:
    tenant = tenant_of(request)
    existing = await _existing(request, tenant, entity_id)
    await store_of(request).write(DeleteSamples(tuple(r.sid for r in existing)))
    return Response(status_code=204, headers=tenant_echo(request))


@router.delete(
    "/temporal/entities/{entity_id:segment}/attrs/{attr_id:segment}",
    status_code=204,
    summary="Delete an attribute's instances",
    **ld_oa.ld_spec(ok_codes={204: "Deleted"}),
)
async def delete_attr_temporal(
    entity_id: str, attr_id: str, request: Request, datasetId: str | None = None, deleteAll: str | None = None
) -> Response:
    tenant = tenant_of(request)
    attribute_name(attr_id)
    every = _flag(deleteAll, "deleteAll")
    existing = await _existing(request, tenant, entity_id)
    named = await _named(request, existing, attr_id)
    refs = [r for r in named if every or r.dataset_id == datasetId]
    if not refs:
        which = "" if every else (" with datasetId " + repr(datasetId[:200]) if datasetId else " (default instance)")
        raise ResourceNotFound(f"entity {entity_id[:200]!r} has no attribute {attr_id[:200]!r}{which}")
    await store_of(request).write(DeleteSamples(tuple(r.sid for r in refs)))
    return Response(status_code=204, headers=tenant_echo(request))


@router.patch(
    "/temporal/entities/{entity_id:segment}/attrs/{attr_id:segment}/{instance_id}",
    status_code=204,
    summary="Modify an attribute instance",
    **ld_oa.ld_spec(ok_codes={204: "Modified"}, body=ld_oa.LD_FRAGMENT_BODY),
)
async def patch_instance(entity_id: str, attr_id: str, instance_id: str, request: Request) -> Response:
    tenant = tenant_of(request)
    _check_instance_path(entity_id, attr_id, instance_id)
    doc, names = await _document(request)
    ref, iid = await _instance(request, tenant, entity_id, attr_id, instance_id)
    sample = _patch_sample(attr_id, doc, names)
    if sample.dataset_id != ref.dataset_id:
        raise BadRequestData(
            f"the instance belongs to datasetId {ref.dataset_id!r}, not {sample.dataset_id!r}; "
            "an instance cannot move to another dataset"
        )
    if not instance_id.startswith(INSTANCE_URN_PREFIX):  # a client's instanceId stays the instance's
        sample.md = _with_instance_id(sample.md, instance_id)
    await store_of(request).write(ReplaceInstance(ref.sid, iid, sample, datetime.now(UTC)))
    return Response(status_code=204, headers=tenant_echo(request))


@router.delete(
    "/temporal/entities/{entity_id:segment}/attrs/{attr_id:segment}/{instance_id}",
    status_code=204,
    summary="Delete an attribute instance",
    **ld_oa.ld_spec(ok_codes={204: "Deleted"}),
)
async def delete_instance(entity_id: str, attr_id: str, instance_id: str, request: Request) -> Response:
    tenant = tenant_of(request)
    _check_instance_path(entity_id, attr_id, instance_id)
    ref, iid = await _instance(request, tenant, entity_id, attr_id, instance_id)
    await store_of(request).write(DeleteInstance(ref.sid, iid))
    return Response(status_code=204, headers=tenant_echo(request))


def _check_instance_path(entity_id: str, attr_id: str, instance_id: str) -> None:
    attribute_name(attr_id)
    uri(instance_id, "the instanceId")


# --- request bodies ------------------------------------------------------------------


@dataclass(frozen=True)
class _Names:
    """What the names of one write mean: its context's term map, and the
    core context's (``stored``: see the module's docstring)."""

    terms: TermMap
    core: TermMap

    def stored(self, name: str) -> str:
        iri = self.terms.expand(name)
        return name if self.core.expand(name) == iri else iri

    def attributes(self, doc: dict) -> dict[str, Any]:
        """The body's attributes by stored name (two spellings of one
        attribute have their instances joined); the entity's ``scope``
        (clause 4.18) as an instance of its ``scope`` Property, at the time
        of the write (``faces.ngsild.scope``)."""
        out: dict[str, list] = {}
        for name, raw in doc.items():
            if name not in _ENTITY_KEYS:
                out.setdefault(self.stored(name), []).extend(raw if type(raw) is list else [raw])
        if "scope" in doc:
            scopes(doc["scope"])  # checked, stored as sent (a string or an array)
            scope: dict[str, Any] = {"type": "Property", "value": doc["scope"]}
            first = _first_observed(out)
            if first is not None:  # the scope holds for the instances it came with (faces.ngsild.service)
                scope["observedAt"] = first
            out.setdefault("scope", []).append(scope)
        return out


async def _document(request: Request) -> tuple[dict, _Names]:
    """The body, and what its names mean (the context may be fetched: off the loop)."""
    doc = await _body(request)
    context = doc["@context"] if "@context" in doc else link_context(request.headers.get("link"))
    return doc, await run_in_threadpool(_names, request, context)


def _names(request: Request, context: Any) -> _Names:
    store = contexts(request)
    return _Names(store.term_map(context), store.term_map(None))


async def _body(request: Request) -> dict:
    """The JSON object sent, with the spec's rules on where ``@context`` goes."""
    media = request.headers.get("content-type", "").split(";")[0].strip().lower()
    if media not in _JSON_TYPES:
        raise UnsupportedMediaType(f"Content-Type must be application/json or application/ld+json, got {media!r}")
    raw = await request.body()  # at most TSDB_MAX_BODY_BYTES (http.bodies)
    try:
        doc = orjson.loads(raw)
    except orjson.JSONDecodeError as exc:
        raise InvalidRequest(f"the body is not valid JSON: {exc}") from None
    if type(doc) is not dict:
        raise InvalidRequest("the body must be a JSON object")
    if (problem := nul_problem(raw, doc)) is not None:  # no backend may store it (parse.text)
        raise BadRequestData(problem)
    if media == "application/ld+json" and "@context" not in doc:
        raise BadRequestData("an application/ld+json body must carry its @context")
    if media == "application/json" and "@context" in doc:
        raise BadRequestData(
            "an application/json body must not carry @context: send it in a Link header, "
            "or send the body as application/ld+json"
        )
    return doc


def _first_observed(attrs: dict[str, list]) -> str | None:
    """The earliest ``observedAt`` among a write's instances, as sent."""
    found = [
        (moment, text)
        for raw in attrs.values()
        for instance in raw
        if type(instance) is dict and isinstance(text := instance.get("observedAt"), str)
        for moment in (_utc(text, "observedAt"),)
        if moment is not None
    ]
    return min(found)[1] if found else None


# The DateTimes of an instance that tell when (clause 4.8): UTC, like every
# NGSI-LD DateTime (clause 4.6.3); an offset other than Z (or +00:00) is refused
# on a write rather than silently moved to UTC.
_UTC_MEMBERS = ("observedAt", "deletedAt")


def _utc(text: str, member: str) -> datetime | None:
    """``text`` as a UTC DateTime; BadRequestData for another offset. None
    when it is no DateTime at all (the instance's own parser says why)."""
    try:
        moment = datetime.fromisoformat(text.replace("Z", "+00:00").replace("z", "+00:00"))
    except ValueError:
        return None
    offset = moment.utcoffset()
    if offset is not None and offset.total_seconds() != 0:
        raise BadRequestData(
            f"{member} {text[:60]!r} has the offset {moment.strftime('%z')}: NGSI-LD DateTimes are UTC "
            "(clause 4.6.3), e.g. 2020-08-01T12:03:00Z"
        )
    return moment.replace(tzinfo=UTC) if offset is None else moment


def _types(value: Any) -> tuple[str, ...]:
    """NGSI-LD allows one type or several; the first names the stored entity."""
    types = [value] if type(value) is str else value
    if type(types) is not list or not types or any(type(t) is not str or not t for t in types):
        raise BadRequestData("the entity type must be a non-empty string or array of strings")
    return tuple(types)


def _flag(value: str | None, name: str) -> bool:
    if value is None or value == "false":
        return False
    if value == "true":
        return True
    raise BadRequestData(f"{name} must be true or false, got {value[:40]!r}")


def _samples(tenant: str, entity_id: str, entity_type: str, attrs: dict, now: datetime) -> list[EntitySample]:
    """Instances → NGSIv2 rows: instances observed at the same time share a
    row, as long as each stored attribute appears once in it."""
    rows: list[EntitySample] = []
    open_rows: dict[datetime, list[EntitySample]] = {}
    given: set[str] = set()
    for name, raw in attrs.items():
        for instance in raw if type(raw) is list else [raw]:
            sample = _instance_sample(name, instance)
            instance_id = client_instance_id(sample.md)
            if instance_id is not None:
                if instance_id in given:
                    raise BadRequestData(f"instanceId {instance_id[:200]!r} is given to two instances")
                given.add(instance_id)
            sample.created_at = sample.modified_at = now
            t = sample.observed_at or sample.deleted_at or now
            for row in open_rows.setdefault(t, []):
                if all(a.name != sample.name for a in row.attrs):
                    row.attrs.append(sample)
                    break
            else:
                row = EntitySample(tenant, "/", entity_id, entity_type, t, [sample])
                open_rows[t].append(row)
                rows.append(row)
    return rows


# Members the system sets: a client's values are ignored (clause 4.8). An
# instanceId a client gives is kept (in ``md``, with the other members),
# unless it is one of ours (a copy of a read answer: a new instance gets
# its own).
_SYSTEM_MEMBERS = ("@context", "createdAt", "modifiedAt")


def _instance_sample(name: str, raw: Any, keep_instance_id: bool = True) -> AttrSample:
    if type(raw) is dict:
        for member in _UTC_MEMBERS:
            if isinstance(raw.get(member), str):
                _utc(raw[member], member)
    if type(raw) is dict and "instanceId" in raw:
        instance_id = raw["instanceId"]
        uri(instance_id, "an instanceId")
        if not keep_instance_id or instance_id.startswith(INSTANCE_URN_PREFIX):
            raw = {k: v for k, v in raw.items() if k != "instanceId"}
    if type(raw) is dict and any(k in raw for k in _SYSTEM_MEMBERS):
        raw = {k: v for k, v in raw.items() if k not in _SYSTEM_MEMBERS}
    try:
        return parse_ld_instance(name, raw)
    except ParseError as exc:
        raise BadRequestData(exc.description) from None


def _patch_sample(attr_id: str, doc: dict, names: _Names) -> AttrSample:
    """The new content: ``{attrId: instance}`` (the attribute under any
    spelling of its name; or a one-instance array), or the instance itself.
    The instance keeps its instanceId: one in the body is not used."""
    wanted = names.terms.expand(attr_id)
    key = next((k for k in doc if k not in _ENTITY_KEYS and names.terms.expand(k) == wanted), None)
    raw: Any = doc[key] if key is not None else doc
    if type(raw) is list:
        if len(raw) != 1:
            raise BadRequestData(f"give exactly one instance of {attr_id[:200]!r}, got {len(raw)}")
        raw = raw[0]
    return _instance_sample(attr_id, raw, keep_instance_id=False)


def _with_instance_id(md: str | None, instance_id: str) -> str:
    """Sub-properties (JSON text) with the instance's client-given instanceId."""
    meta = orjson.loads(md) if md else {}
    meta["instanceId"] = instance_id
    return orjson.dumps(meta).decode()


# --- what is stored ------------------------------------------------------------------


def _entity_series(request: Request, tenant: str, entity_id: str, with_samples: bool) -> list[SeriesRef]:
    """The entity's series that hold instances (any type, any service path)."""
    q = store_of(request).querier()
    refs = q.series(SeriesSelect(Scope(tenant), EntityFilter(ids=(entity_id,))))
    if not with_samples or not refs:
        return refs
    live = q.sids_with_samples([r.sid for r in refs])
    return [r for r in refs if r.sid in live]


async def _existing(request: Request, tenant: str, entity_id: str) -> list[SeriesRef]:
    def look() -> list[SeriesRef]:
        tell = caller_of(request) is None  # with authentication on, do not tell which tenants exist
        if tell and tenant and tenant not in store_of(request).querier().tenants():
            raise NonexistentTenant(f"tenant {tenant!r} does not exist")
        return _entity_series(request, tenant, entity_id, True)

    refs = await store_of(request).read(look, memory_first=False)
    if not refs:
        uri(entity_id, "the entity id")  # what no entity has is a 400 when it is no id at all
        raise ResourceNotFound(f"entity {entity_id[:200]!r} has no temporal representation")
    return refs


def _entity_type(existing: Sequence[SeriesRef], types: Sequence[str], entity_id: str) -> str:
    """The type the write's instances are stored under. An entity's types
    are the union of those it was written with (clauses 4.16, 5.6.11: an
    upsert unites the types): the reads take every stored type of an id as
    its types. So a write naming a type the entity does not have yet is
    stored under that type (the first such), one naming only known types
    under its first, one naming none under the stored type."""
    stored = sorted({r.entity_type for r in existing})
    if not types:
        if not stored:
            raise BadRequestData(f"entity {entity_id[:200]!r} needs a type")
        return stored[0]
    new = [t for t in types if t not in stored]
    return new[0] if new else types[0]


async def _named(request: Request, existing: Sequence[SeriesRef], attr_id: str) -> list[SeriesRef]:
    """The series of ``existing`` of the attribute a URL names, both read
    with the request's ``Link`` context (as the reads read stored names)."""

    def look() -> list[SeriesRef]:
        terms = contexts(request).term_map(link_context(request.headers.get("link")))
        wanted = terms.expand(attr_id)
        names = list({r.ld_attr for r in existing})
        iris = dict(zip(names, terms.expand_all(names), strict=True))
        return [r for r in existing if iris[r.ld_attr] == wanted]

    return await run_in_threadpool(look)


async def _instance(
    request: Request, tenant: str, entity_id: str, attr_id: str, instance_id: str
) -> tuple[SeriesRef, int]:
    """The series and instance id an instanceId names, or 404."""
    existing = await _existing(request, tenant, entity_id)
    refs = await _named(request, existing, attr_id)
    missing = f"no instance {instance_id[:200]!r} of attribute {attr_id[:200]!r} of entity {entity_id[:200]!r}"
    if not refs:
        raise ResourceNotFound(missing)
    store = store_of(request)
    lookup = InstanceLookup([r.sid for r in refs], instance_id)
    found = await store.read(partial(store.querier().instance_at, lookup), memory_first=False)
    if found is None:
        raise ResourceNotFound(missing)
    return next(r for r in refs if r.sid == found[0]), found[1]
