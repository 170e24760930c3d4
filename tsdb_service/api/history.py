"""Shared plumbing of the history routes: parse, query, render.

DuckDB blocks, so no read may query it on the event loop. The history routes
first try to answer from memory (series catalog, in-memory tails) on the
loop, where any database access raises instead of running, and otherwise
answer in the threadpool (see ``storage.memory_only``).
"""

from __future__ import annotations

from fastapi import Request
from starlette.concurrency import run_in_threadpool

from ..history.params import history_query
from ..history.service import run_history
from ..history.shape import render
from ..query import Shape
from ..storage.memory_only import in_memory_or_threadpool
from .responses import JSON
from .tenancy import tenant_of


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
    result = run_history(app.state.store.querier(), query)
    return JSON(render(result))


async def answer_history_async(request: Request, shape: Shape, **kwargs) -> JSON:
    """``answer_history`` from memory on the event loop when it can be, else
    in the threadpool. A geo-query goes straight to the threadpool: its
    matching is work that a retry there would repeat."""
    if "georel" in request.query_params:
        return await run_in_threadpool(answer_history, request, shape, **kwargs)
    return await in_memory_or_threadpool(answer_history, request, shape, **kwargs)
