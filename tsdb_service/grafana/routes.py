"""``GET /dashboards`` and ``GET /dashboards/{use_case}``: the shipped dashboards as JSON.

The JSON is what ``dashboards/<use case>.json`` holds (built by the same
code); import it in Grafana, or provision ``dashboards/`` (see its README).
The dashboard builder is imported on first use, so ``serve`` starts fast.
"""

from __future__ import annotations

from fastapi import APIRouter, Request

from ..api import openapi as oa
from ..api.responses import JSON
from ..errors import NotFound

router = APIRouter(tags=["grafana"])


@router.get("/dashboards", summary="The use-case dashboards", **oa.DASHBOARDS)
def list_dashboards(request: Request) -> JSON:
    from . import dashboards

    out = []
    for name in dashboards.BUILDERS:
        doc = dashboards.build(name)
        out.append({
            "use_case": name,
            "uid": doc["uid"],
            "title": doc["title"],
            "tags": doc.get("tags", []),
            "url": f"{request.url.path.rstrip('/')}/{name}",
            "datasource_uid": dashboards.kit.DATASOURCES[name].uid,
        })  # fmt: skip
    return JSON(out)


@router.get("/dashboards/{use_case}", summary="One dashboard's JSON (schemaVersion 42)", **oa.DASHBOARD)
def get_dashboard(use_case: str) -> JSON:
    from . import dashboards

    if use_case.endswith(".json"):
        use_case = use_case[: -len(".json")]
    if use_case not in dashboards.BUILDERS:
        raise NotFound(f"no dashboard {use_case[:60]!r}: choose from {', '.join(dashboards.BUILDERS)}")
    return JSON(dashboards.build(use_case))
