"""``GET /dashboards`` and ``GET /dashboards/{name}``: the shipped dashboards as JSON;
``GET /dashboards/provisioning/{file}``: Grafana's provisioning files for them.

The JSON is what ``dashboards/<name>.json`` holds (the three use cases and
``service``, the service's own; built by the same code); import it in
Grafana, or provision ``dashboards/`` (see its README). People read the
list on the explorer's dashboards page (``/ui/#/dashboards``), which links
here. The datasources file names this service at the URL Grafana reaches it
by (``?url=``), since the dashboards refer to their datasources by uid and
Grafana's form cannot set one.
The dashboard builder is imported on first use, so ``serve`` starts fast.
"""

from __future__ import annotations

from fastapi import APIRouter, Request
from fastapi.responses import PlainTextResponse

from tsdb_service.core.errors import NotFound
from tsdb_service.faces.grafana import openapi as grafana_oa
from tsdb_service.faces.grafana.params import service_url
from tsdb_service.http.responses import JSON

PROVISIONING_FILES = ("datasources.yaml", "dashboards.yaml")

router = APIRouter(tags=["grafana"])


@router.get("/dashboards", summary="The use-case dashboards", **grafana_oa.DASHBOARDS)
def list_dashboards(request: Request) -> JSON:
    """Every shipped dashboard: the use cases' (``use_case`` names it) and the
    service's own (``use_case`` null), with what it shows (``description``,
    and ``sections``: its panels' titles under each row's).
    ``datasources`` are the ``{"type", "uid"}`` its panels read, taken from
    the dashboard itself: the use cases read Infinity, the service dashboard
    Prometheus."""
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
                "description": doc.get("description", ""),
                "sections": _sections(doc),
                "tags": doc.get("tags", []),
                "url": f"{request.url.path.rstrip('/')}/{name}",
                "datasources": sources,
                "datasource_uid": sources[0]["uid"] if sources else None,
            }
        )
    return JSON(out)


def _sections(doc: dict) -> list[dict]:
    """``[{"title": row title or None, "panels": [titles]}]``, in the dashboard's order."""
    sections: list[dict] = []
    for panel in doc.get("panels", []):
        if panel.get("type") == "row":  # a collapsed row holds its panels
            inner = [one.get("title") or one.get("type") for one in panel.get("panels", [])]
            sections.append({"title": panel.get("title"), "panels": inner})
            continue
        if not sections:
            sections.append({"title": None, "panels": []})
        sections[-1]["panels"].append(panel.get("title") or panel.get("type"))
    return [section for section in sections if section["panels"]]


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


@router.get(
    "/dashboards/provisioning/{file}",
    summary="Grafana provisioning files for the dashboards' datasources and folder",
    **grafana_oa.PROVISIONING,
)
def provisioning_file(file: str, request: Request) -> PlainTextResponse:
    """``datasources.yaml``: the datasources the dashboards refer to by uid,
    pointing at ``?url=`` (default ``http://tsdb-service:8668``, the compose
    name); ``dashboards.yaml``: the file provider for the JSON files."""
    from tsdb_service.faces.grafana import dashboards
    from tsdb_service.faces.grafana.dashboards import kit

    if file not in PROVISIONING_FILES:
        raise NotFound(f"no provisioning file {file[:60]!r}: choose from {', '.join(PROVISIONING_FILES)}")
    if file == "datasources.yaml":
        text = dashboards.datasources_yaml(service_url(request.query_params.get("url"), kit.SERVICE_URL))
    else:
        text = dashboards.dashboards_yaml()
    return PlainTextResponse(text, media_type="application/yaml")


@router.get("/dashboards/{use_case}", summary="One dashboard's JSON (schemaVersion 42)", **grafana_oa.DASHBOARD)
def get_dashboard(use_case: str) -> JSON:
    from tsdb_service.faces.grafana import dashboards

    if use_case.endswith(".json"):
        use_case = use_case[: -len(".json")]
    if use_case not in dashboards.DASHBOARDS:
        raise NotFound(f"no dashboard {use_case[:60]!r}: choose from {', '.join(dashboards.DASHBOARDS)}")
    return JSON(dashboards.build(use_case))
