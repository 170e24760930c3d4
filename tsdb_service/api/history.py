"""Shared plumbing of the history routes: parse, query, render.

Read routes are plain ``def``: DuckDB blocks, so FastAPI runs them in its
threadpool and the event loop stays free for notifications.
"""

from __future__ import annotations

from fastapi import Request

from ..history.params import history_query
from ..history.query import Shape
from ..history.service import run_history
from ..history.shape import render
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
