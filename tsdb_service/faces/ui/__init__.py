"""The built-in explorer (``/ui``) and the offline API docs (``/docs``).

A plain HTML/JS/CSS page shipped in ``static/`` that reads the service's own
HTTP API (the Grafana Infinity rows and ``/ui/tenants``), so the use cases
can be seen without a Grafana server and without internet access. The
third-party assets it needs (uPlot, Swagger UI) are vendored under
``static/vendor/`` with their licences.

``router`` carries every route; ``app.include_router(ui.router)``, with the
app created with ``docs_url=None`` and ``redoc_url=None`` so ``/docs`` here
replaces FastAPI's CDN-backed one.
"""

from __future__ import annotations

from tsdb_service.faces.ui.routes import router

__all__ = ["router"]
