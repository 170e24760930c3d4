"""Shared plumbing of the history routes: parse, query, render.

No read may query the database on the event loop: the history routes read
through ``Store.read``, which answers from memory (series catalog, in-memory
tails) on the loop when it can and otherwise in the threadpool.
"""

from __future__ import annotations

from functools import partial

from fastapi import Request

from tsdb_service.core.query import Shape
from tsdb_service.faces.quantumleap.params import history_query
from tsdb_service.faces.quantumleap.shape import render
from tsdb_service.history.service import run_history
from tsdb_service.http.responses import JSON
from tsdb_service.http.store import store_of
from tsdb_service.http.tenancy import tenant_of


def answer_history(
    request: Request,
    shape: Shape,
    *,
    entity_id: str | None = None,
    entity_type: str | None = None,
    attr: str | None = None,
    values_only: bool = False,
) -> JSON:
    app = request.app
    query = history_query(
        shape,
        request.query_params,
        request.headers,
        tenant_of(request),
        app.state.settings.default_limit,
        entity_id=entity_id,
        entity_type=entity_type,
        attr=attr,
        values_only=values_only,
    )
    result = run_history(store_of(request).querier(), query)
    return JSON(render(result))


async def answer_history_async(request: Request, shape: Shape, **kwargs) -> JSON:
    """``answer_history`` from memory on the event loop when it can be, else
    in the threadpool. A geo-query goes straight to the threadpool: its
    matching is work that a retry there would repeat."""
    read = partial(answer_history, request, shape, **kwargs)
    return await store_of(request).read(read, memory_first="georel" not in request.query_params)
