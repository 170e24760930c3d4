"""The explorer's server side: its page and files, the tenant list, the
use-case description, and ``/docs`` served from the package, not a CDN.

The page itself is exercised in a real browser by ``test_ui_browser``.
"""

from __future__ import annotations

import re

import pytest

from tsdb_service.faces.ui.routes import STATIC
from tsdb_service.usecases import enums, sites


def _entity(eid: str, etype: str, **attrs) -> dict:
    return {"id": eid, "type": etype, **{name: {"type": "Number", "value": value} for name, value in attrs.items()}}


def _notify(client, notify, tenant: str | None, path: str, *entities: dict) -> None:
    headers = {"Fiware-ServicePath": path}
    if tenant is not None:
        headers["Fiware-Service"] = tenant
    notify(client, {"subscriptionId": "s", "data": list(entities)}, headers)


def test_tenants_lists_every_tenant_with_its_service_paths_and_counts(client, notify):
    assert client.get("/ui/tenants").json() == []
    _notify(client, notify, "Farm", "/north", _entity("urn:a", "Sensor", t=1, h=2), _entity("urn:b", "Sensor", t=3))
    _notify(client, notify, "farm", "/south/field", _entity("urn:c", "Robot", speed=1.5))
    _notify(client, notify, None, "/", _entity("urn:d", "Thing", x=1))
    tenants = client.get("/ui/tenants").json()
    assert tenants == [
        {"tenant": "", "servicePaths": ["/"], "types": ["Thing"], "entities": 1, "series": 1},
        {
            "tenant": "farm",
            "servicePaths": ["/north", "/south/field"],
            "types": ["Robot", "Sensor"],
            "entities": 3,
            "series": 4,
        },
    ]


def test_usecases_describe_the_demo_from_its_own_definitions(client):
    described = client.get("/ui/usecases").json()
    assert set(described) == {"lawnmower", "warehouse", "drone"}
    assert described["lawnmower"]["entity"] == sites.LAWNMOWER_ID
    assert (described["lawnmower"]["service"], described["lawnmower"]["servicePath"]) == ("lawnmower", "/bosch")
    garden = described["lawnmower"]["garden"]
    assert garden[0] == garden[-1] and garden[0] == pytest.approx(list(sites.GARDEN_ORIGIN))
    assert described["warehouse"]["robot"] == sites.WAREHOUSE_ROBOT_ID
    assert described["warehouse"]["enums"]["doorState"] == {str(k): v for k, v in enums.DOOR_STATE.items()}
    drone = described["drone"]
    assert [s["priority"] for s in drone["sensors"]] == [0.075, 0.075, 0.075, 0.175, 0.1, 0.2, 0.125, 0.175]
    assert [s["id"] for s in drone["sensors"]] == list(sites.SENSOR_IDS)
    assert drone["enums"]["missionState"]["3"] == "reading sensor"


def test_ui_redirects_to_the_page_and_the_page_loads_its_files(client):
    moved = client.get("/ui", follow_redirects=False)
    assert moved.status_code == 307 and moved.headers["location"] == "ui/"
    page = client.get("/ui/")
    assert page.status_code == 200 and page.headers["content-type"].startswith("text/html")
    referenced = re.findall(r'(?:src|href)="(static/[^"]+)"', page.text)
    assert "static/explorer.js" in referenced and "static/vendor/uplot/uPlot.iife.min.js" in referenced
    for ref in referenced:
        asset = client.get(f"/ui/{ref}")
        assert asset.status_code == 200, ref
        assert asset.content == (STATIC / ref.removeprefix("static/")).read_bytes()
    script_type = client.get("/ui/static/explorer.js").headers["content-type"]
    assert script_type.startswith(("text/javascript", "application/javascript"))
    assert client.get("/ui/static/explorer.css").headers["content-type"].startswith("text/css")


@pytest.mark.parametrize("name", ["nope.js", "../routes.py", "..%2Froutes.py", "vendor/../../routes.py", ""])
def test_only_shipped_files_are_served(client, name):
    response = client.get(f"/ui/static/{name}")
    assert response.status_code == 404
    assert response.json()["error"] == "NotFound"


def test_vendored_libraries_carry_their_licences():
    vendor = STATIC / "vendor"
    assert "MIT License" in (vendor / "uplot" / "LICENSE").read_text()
    assert "Apache License" in (vendor / "swagger-ui" / "LICENSE").read_text()
    note = (vendor / "README.md").read_text()
    assert "| `uplot` | 1.6.32 |" in note and "| `swagger-ui-dist` | 5.35.0 |" in note
    assert "v1.6.32" in (vendor / "uplot" / "uPlot.iife.min.js").read_text()[:200]


def test_docs_use_the_packaged_swagger_ui_and_nothing_else(client):
    page = client.get("/docs")
    assert page.status_code == 200
    urls = re.findall(r"""(?:src|href|url)\s*[:=]\s*['"]([^'"]+)['"]""", page.text)
    assert urls, page.text
    assert not [u for u in urls if "://" in u or u.startswith("//")], urls
    for url in urls:
        assert client.get(url).status_code == 200, url
    assert "/ui/static/vendor/swagger-ui/swagger-ui-bundle.js" in urls
    assert '"validatorUrl": null' in page.text
    assert client.get("/openapi.json").json()["info"]["title"] == "tsdb-service"
    assert client.get("/redoc").status_code == 404
