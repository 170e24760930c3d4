"""Routes of the explorer page, its static files, its small JSON helpers and ``/docs``.

Static files are looked up in a table built once from the package's
``static/`` directory: a request can only name a file we ship, so there is
no path to traverse. Routes that read the store run through ``Store.read``
(``@reads_store``): the store blocks, so they run in the threadpool.
"""

from __future__ import annotations

import mimetypes
from functools import cache
from pathlib import Path

from fastapi import APIRouter, Request
from fastapi.openapi.docs import get_swagger_ui_html
from fastapi.responses import FileResponse, HTMLResponse, RedirectResponse

from tsdb_service.core.errors import NotFound
from tsdb_service.core.query import EntityFilter, Scope
from tsdb_service.faces.ui import openapi as ui_oa
from tsdb_service.http.responses import JSON
from tsdb_service.http.store import reads_store, store_of
from tsdb_service.http.tenancy import visible
from tsdb_service.read.requests import SeriesSelect

STATIC = Path(__file__).resolve().parent / "static"
SWAGGER = "vendor/swagger-ui"
# Our own files change with each release; vendored ones only with their version.
CACHE_OWN = "no-cache"
CACHE_VENDOR = "public, max-age=86400"

router = APIRouter(tags=["explorer"])


@cache
def _static_files() -> dict[str, Path]:
    """``relative/name`` → file, for every file shipped under ``static/``."""
    return {path.relative_to(STATIC).as_posix(): path for path in STATIC.rglob("*") if path.is_file()}


@router.get("/ui", include_in_schema=False)
def explorer_root() -> RedirectResponse:
    """``/ui`` → ``/ui/``: the page uses relative URLs, so it works behind a path prefix."""
    return RedirectResponse("ui/", status_code=307)


@router.get("/ui/", summary="The explorer page", response_class=HTMLResponse, **ui_oa.UI_PAGE)
def explorer_page() -> FileResponse:
    return FileResponse(STATIC / "index.html", media_type="text/html", headers={"Cache-Control": CACHE_OWN})


@router.get("/ui/static/{name:path}", include_in_schema=False)
def static_file(name: str) -> FileResponse:
    path = _static_files().get(name)
    if path is None:
        raise NotFound(f"no explorer file {name[:80]!r}")
    media_type = mimetypes.guess_type(path.name)[0] or "application/octet-stream"
    if media_type.startswith("text/") or media_type.endswith("javascript"):
        media_type += "; charset=utf-8"
    cache_control = CACHE_VENDOR if name.startswith("vendor/") else CACHE_OWN
    return FileResponse(path, media_type=media_type, headers={"Cache-Control": cache_control})


@router.get("/ui/tenants", summary="Tenants that have stored series, with their service paths", **ui_oa.UI_TENANTS)
@reads_store
def tenants(request: Request) -> JSON:
    """``[{"tenant", "servicePaths", "types", "entities", "series"}]``. The
    tenant ``""`` is Orion's default one (no ``Fiware-Service``). With
    authentication on, only the tenants the credential may touch."""
    querier = store_of(request).querier()
    out = []
    for tenant in visible(request, querier.tenants()):
        refs = querier.series(SeriesSelect(Scope(tenant), EntityFilter()))
        out.append(
            {
                "tenant": tenant,
                "servicePaths": sorted({ref.service_path for ref in refs}),
                "types": sorted({ref.entity_type for ref in refs}),
                "entities": len({(ref.entity_id, ref.entity_type) for ref in refs}),
                "series": len(refs),
            }
        )
    return JSON(out)


@router.get(
    "/ui/usecases", summary="What the explorer's use-case views show: tenancy, ids, enumerations", **ui_oa.UI_USECASES
)
def usecases() -> JSON:
    """From the demo's own definitions, so a renamed entity or state cannot
    drift between the simulators and the page."""
    from tsdb_service.faces.ui.usecases import describe

    return JSON(describe())


@router.get("/docs", include_in_schema=False)
def swagger_ui(request: Request) -> HTMLResponse:
    """Swagger UI from the package's vendored copy: no CDN, works offline."""
    root = request.scope.get("root_path", "").rstrip("/")
    assets = f"{root}/ui/static/{SWAGGER}"
    return get_swagger_ui_html(
        openapi_url=f"{root}{request.app.openapi_url}",
        title=f"{request.app.title} - API docs",
        swagger_js_url=f"{assets}/swagger-ui-bundle.js",
        swagger_css_url=f"{assets}/swagger-ui.css",
        swagger_favicon_url=f"{assets}/favicon-32x32.png",
        oauth2_redirect_url=None,
        # No "valid" badge fetched from validator.swagger.io.
        swagger_ui_parameters={"validatorUrl": None},
    )
