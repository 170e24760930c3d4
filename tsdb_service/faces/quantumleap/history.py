"""The history routes: QuantumLeap's twelve ways to ask for samples, one table.

Every route parses its query into a ``HistoryQuery`` of its ``Shape`` (by
entity, by type, by attribute; with or without values only), answers it
through ``history.service`` and renders QuantumLeap 1.0's JSON (``shape``).
No read may query the database on the event loop: the routes read through
``Store.read``, which answers from memory (series catalog, in-memory tails)
on the loop when it can and otherwise in the threadpool.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial

from fastapi import APIRouter, Request

from tsdb_service.core.query import Shape
from tsdb_service.faces.quantumleap import openapi as ql_oa
from tsdb_service.faces.quantumleap.paging import limit_headers
from tsdb_service.faces.quantumleap.params import history_query
from tsdb_service.faces.quantumleap.shape import render
from tsdb_service.history.service import run_history
from tsdb_service.http import openapi as oa
from tsdb_service.http.responses import JSON
from tsdb_service.http.store import store_of
from tsdb_service.http.tenancy import tenant_of


def answer_history(request: Request, shape: Shape, values_only: bool) -> JSON:
    """Parse, answer and render one history request (path parameters
    ``entity_id``, ``entity_type``, ``attr_name`` as its route has them)."""
    path = request.path_params
    query = history_query(
        shape,
        request.query_params,
        request.headers,
        tenant_of(request),
        request.app.state.settings.default_limit,
        entity_id=path.get("entity_id"),
        entity_type=path.get("entity_type"),
        attr=path.get("attr_name"),
        values_only=values_only,
    )
    result = run_history(store_of(request).querier(), query)
    headers = limit_headers(request, query.limit, query.offset, _rows_per_type(result))
    return JSON(render(result), headers=headers or None)


def _rows_per_type(result) -> list[int]:
    """Rows answered per entity type (QuantumLeap's limit applies to each), or
    in all for a global aggregate."""
    counts: dict[str, int] = {}
    for ent in result.entities:
        size = len(ent.index) if ent.index else max((len(v) for v in ent.columns.values()), default=0)
        counts[ent.entity_type] = counts.get(ent.entity_type, 0) + size
    return list(counts.values())


@dataclass(frozen=True, slots=True)
class HistoryRoute:
    """One history route: where, which shape of answer, and its description."""

    name: str  # the operation's name (and the OpenAPI operationId's stem)
    path: str
    shape: Shape
    values_only: bool
    schema: str  # the answer's component schema
    summary: str

    def endpoint(self):
        shape, values_only = self.shape, self.values_only

        async def answer(request: Request) -> JSON:
            """From memory on the event loop when it can be, else in the
            threadpool. A geo-query goes straight to the threadpool: its
            matching is work that a retry there would repeat."""
            read = partial(answer_history, request, shape, values_only)
            return await store_of(request).read(read, memory_first="georel" not in request.query_params)

        answer.__name__ = self.name
        return answer

    def parameters(self) -> list[dict]:
        """The path's own parameters, then the shape's query parameters."""
        names = [segment[1:-1] for segment in self.path.split("/") if segment.startswith("{")]
        path = [{"name": n, "in": "path", "required": True, "schema": {"type": "string"}} for n in names]
        by_prefix = {
            "/v2/entities": ql_oa.ENTITY_HISTORY,
            "/v2/types": ql_oa.TYPE_HISTORY,
            "/v2/attrs": ql_oa.ANY_HISTORY,
        }
        return path + next(params for prefix, params in by_prefix.items() if self.path.startswith(prefix))

    @property
    def tag(self) -> str:
        return self.path.split("/")[2]


_QUERY_PARAMETERS = {"entities": ql_oa.ENTITY_HISTORY, "types": ql_oa.TYPE_HISTORY, "attrs": ql_oa.ANY_HISTORY}
E, EA, T, TA, A, AS = Shape.ENTITY, Shape.ENTITY_ATTR, Shape.TYPE, Shape.TYPE_ATTR, Shape.ATTR, Shape.ATTRS
ROUTES = (
    HistoryRoute("entity", "/v2/entities/{entity_id}", E, False, "EntityHistory",
                 "History of N attributes of one entity"),
    HistoryRoute("entity_value", "/v2/entities/{entity_id}/value", E, True, "EntityValues",
                 "History of N attributes of one entity (values only)"),
    HistoryRoute("entity_attr", "/v2/entities/{entity_id}/attrs/{attr_name}", EA, False, "EntityAttrHistory",
                 "History of one attribute of one entity"),
    HistoryRoute("entity_attr_value", "/v2/entities/{entity_id}/attrs/{attr_name}/value", EA, True, "EntityAttrValues",
                 "History of one attribute of one entity (values only)"),
    HistoryRoute("entity_type", "/v2/types/{entity_type}", T, False, "TypeHistory",
                 "History of N attributes of the entities of a type"),
    HistoryRoute("entity_type_value", "/v2/types/{entity_type}/value", T, True, "TypeValues",
                 "History of N attributes of a type's entities (values only)"),
    HistoryRoute("type_attr", "/v2/types/{entity_type}/attrs/{attr_name}", TA, False, "TypeAttrHistory",
                 "History of one attribute of a type's entities"),
    HistoryRoute("type_attr_value", "/v2/types/{entity_type}/attrs/{attr_name}/value", TA, True, "TypeAttrValues",
                 "History of one attribute of a type's entities (values only)"),
    HistoryRoute("attrs", "/v2/attrs", AS, False, "AttrsHistory", "History of N attributes of every entity"),
    HistoryRoute("attrs_value", "/v2/attrs/value", AS, True, "AttrsValues",
                 "History of N attributes of every entity (values only)"),
    HistoryRoute("attr", "/v2/attrs/{attr_name}", A, False, "AttrHistory", "History of one attribute of every entity"),
    HistoryRoute("attr_value", "/v2/attrs/{attr_name}/value", A, True, "AttrValues",
                 "History of one attribute of every entity (values only)"),
)  # fmt: skip

router = APIRouter()
for route in ROUTES:
    router.add_api_route(
        route.path,
        route.endpoint(),
        methods=["GET"],
        name=route.name,
        tags=[route.tag],
        summary=route.summary,
        **oa.spec(*route.parameters(), ok_=oa.ok(ql_oa.maybe_empty(route.schema)), errors_=ql_oa.HISTORY_ERRORS),
    )
