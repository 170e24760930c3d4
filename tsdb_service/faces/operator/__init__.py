"""What an operator asks of the service itself: version, health, the API
index, the Prometheus metrics (``meta``) and backups (``backup``).
``router`` carries the routes."""

from __future__ import annotations

from fastapi import APIRouter

from tsdb_service.faces.operator import backup, meta

router = APIRouter()
for _routes in (meta, backup):
    router.include_router(_routes.router)

__all__ = ["router"]
