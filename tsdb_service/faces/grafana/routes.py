"""``GET /dashboards`` and ``GET /dashboards/{name}``: the shipped dashboards as JSON.

The JSON is what ``dashboards/<name>.json`` holds (the three use cases and
``service``, the service's own; built by the same code); import it in
Grafana, or provision ``dashboards/`` (see its README).
The dashboard builder is imported on first use, so ``serve`` starts fast.
"""

from __future__ import annotations

from fastapi import APIRouter, Request

from tsdb_service.core.errors import NotFound
from tsdb_service.faces.grafana import openapi as grafana_oa
from tsdb_service.http.responses import JSON

router = APIRouter(tags=["grafana"])


@router.get("/dashboards", summary="The use-case dashboards", **grafana_oa.DASHBOARDS)
def list_dashboards(request: Request) -> JSON:
    """Every shipped dashboard: the use cases' (``use_case`` names it) and the
    service's own (``use_case`` null). ``datasources`` are the ``{"type",
    "uid"}`` its panels read, taken from the dashboard itself: the use cases
    read Infinity, the service dashboard Prometheus."""
    from tsdb_service.faces.grafana import dashboards

    out = []
    for name in dashboards.DASHBOARDS:
        doc = dashboards.build(name)
        sources = _datasources(doc)
        out.append(
            {
                "name": name,
                "use_case": name if name in dashboards.BUILDERS else None,
                "uid": doc["uid"],
                "title": doc["title"],
                "tags": doc.get("tags", []),
                "url": f"{request.url.path.rstrip('/')}/{name}",
                "datasources": sources,
                "datasource_uid": sources[0]["uid"] if sources else None,
            }
        )
    return JSON(out)


def _datasources(node, found: list[dict] | None = None) -> list[dict]:
    """The distinct ``{"type", "uid"}`` datasource references in a dashboard, in order."""
    found = [] if found is None else found
    if isinstance(node, dict):
        ref = node.get("datasource")
        if isinstance(ref, dict) and ref.get("uid"):
            entry = {"type": ref.get("type"), "uid": ref["uid"]}
            if entry not in found:
                found.append(entry)
        for value in node.values():
            _datasources(value, found)
    elif isinstance(node, list):
        for value in node:
            _datasources(value, found)
    return found


@router.get("/dashboards/{use_case}", summary="One dashboard's JSON (schemaVersion 42)", **grafana_oa.DASHBOARD)
def get_dashboard(use_case: str) -> JSON:
    from tsdb_service.faces.grafana import dashboards

    if use_case.endswith(".json"):
        use_case = use_case[: -len(".json")]
    if use_case not in dashboards.DASHBOARDS:
        raise NotFound(f"no dashboard {use_case[:60]!r}: choose from {', '.join(dashboards.DASHBOARDS)}")
    return JSON(dashboards.build(use_case))
