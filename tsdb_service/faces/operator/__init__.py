"""What an operator asks of the service itself: version, health, the API
index and the Prometheus metrics. ``router`` carries the routes."""

from __future__ import annotations

from tsdb_service.faces.operator.meta import router

__all__ = ["router"]
