"""The use-case dashboards and the service's own, built in code, and their
Grafana provisioning files.

``build(name)`` gives a dashboard as JSON data; ``write(folder)`` regenerates
``<name>.json`` for every use case, ``drone-ld.json`` (the drone through the
NGSI-LD temporal API) and ``service.json`` (tsdb-service itself, from
Prometheus), plus ``provisioning/dashboards.yaml`` and
``provisioning/datasources.yaml`` (``tsdb-service dashboards build``).
"""

from __future__ import annotations

from collections.abc import Callable
from functools import cache
from pathlib import Path

from tsdb_service.faces.grafana.dashboards import drone, drone_ld, kit, lawnmower, service, warehouse

BUILDERS: dict[str, Callable] = {
    "lawnmower": lawnmower.build,
    "warehouse": warehouse.build,
    "drone": drone.build,
}
# Every dashboard written to dashboards/: the use cases, the drone through
# the NGSI-LD temporal API, and the service's own.
DASHBOARDS: dict[str, Callable] = {**BUILDERS, "drone-ld": drone_ld.build, "service": service.build}
TITLES = {"lawnmower": "Bosch lawnmower", "warehouse": "PIAP smart warehouse", "drone": "eProsima drone"}
FOLDER = "tsdb-service"
# Where `dashboards/` is mounted inside the Grafana container (see dashboards/README.md).
GRAFANA_PATH = "/var/lib/grafana/dashboards/tsdb-service"


@cache
def _cached(name: str) -> bytes:
    import orjson

    return orjson.dumps(kit.to_json(DASHBOARDS[name]()))


def build(name: str) -> dict:
    """One dashboard's JSON (a fresh copy); ``KeyError`` for an unknown name."""
    import orjson

    return orjson.loads(_cached(name))


def dumps(doc) -> str:
    import json

    return json.dumps(doc, indent=2, ensure_ascii=False) + "\n"


def datasources_yaml(service_url: str = kit.SERVICE_URL) -> str:
    lines = [
        "# Grafana datasource provisioning for tsdb-service (generated: tsdb-service dashboards build).",
        "# One Infinity datasource per use case; the tenant and service path travel as custom",
        "# HTTP headers, exactly as Orion's notifications carry them. Change `url` (and",
        "# allowedHosts) if tsdb-service is not reachable from Grafana as " + service_url + ".",
        "# Needs the Infinity plugin: GF_PLUGINS_PREINSTALL=yesoreyeram-infinity-datasource",
        "apiVersion: 1",
        "datasources:",
    ]
    for ds in kit.DATASOURCES.values():
        lines += [
            f"  - name: {ds.name}",
            f"    uid: {ds.uid}",
            f"    type: {kit.INFINITY}",
            "    access: proxy",
            f"    url: {service_url}",
            "    editable: true",
            "    jsonData:",
            "      allowedHosts:",
            f"        - {service_url}",
            "      httpHeaderName1: Fiware-Service",
            "      httpHeaderName2: Fiware-ServicePath",
            "    secureJsonData:",
            f"      httpHeaderValue1: {ds.tenancy.service}",
            f"      httpHeaderValue2: {ds.tenancy.service_path}",
        ]
    lines += [
        "  # Prometheus scraping tsdb-service's /metrics, for the service dashboard (service.json).",
        f"  - name: {service.DS.name}",
        f"    uid: {service.DS.uid}",
        f"    type: {service.PROMETHEUS}",
        "    access: proxy",
        f"    url: {service.PROMETHEUS_URL}",
        "    editable: true",
    ]
    return "\n".join(lines) + "\n"


def dashboards_yaml() -> str:
    return (
        "\n".join(
            [
                "# Grafana dashboard provisioning for tsdb-service (generated: tsdb-service dashboards build).",
                f"# Mount this repository's dashboards/ folder at {GRAFANA_PATH}.",
                "apiVersion: 1",
                "providers:",
                "  - name: tsdb-service",
                "    orgId: 1",
                f"    folder: {FOLDER}",
                "    type: file",
                "    disableDeletion: false",
                "    allowUiUpdates: true",
                "    updateIntervalSeconds: 30",
                "    options:",
                f"      path: {GRAFANA_PATH}",
                "      foldersFromFilesStructure: false",
            ]
        )
        + "\n"
    )


def files() -> dict[str, str]:
    """Relative path → content of everything ``write`` produces."""
    out = {f"{name}.json": dumps(build(name)) for name in DASHBOARDS}
    out["provisioning/dashboards.yaml"] = dashboards_yaml()
    out["provisioning/datasources.yaml"] = datasources_yaml()
    return out


def write(folder: Path) -> list[Path]:
    written = []
    for relative, content in files().items():
        path = folder / relative
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(content)
        written.append(path)
    return written
