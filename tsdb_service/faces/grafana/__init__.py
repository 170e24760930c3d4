"""Grafana, served natively: Infinity and SimpleJSON datasource APIs, and the
use-case dashboards (``dashboards/``, built by ``tsdb-service dashboards build``).

``router`` carries every Grafana route; ``app.include_router(grafana.router)``.
"""

from __future__ import annotations

from fastapi import APIRouter

from tsdb_service.faces.grafana import infinity, routes, simplejson

router = APIRouter()
router.include_router(infinity.router)
router.include_router(simplejson.router)
router.include_router(routes.router)

__all__ = ["router"]
