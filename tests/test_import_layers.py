"""The import graph is the one README's "How it is built" draws: vocabulary,
parsing, storage, reading, HTTP, each importing only the layers below it.

Read from the source with ``ast`` (no import side effects), so a new import
that goes back up fails here with the module and the name it imported.
"""

from __future__ import annotations

import pytest

from tests.support.imports import import_graph

# Layer 1: what both sides of the seams speak; imports only itself.
VOCABULARY = {"model", "query", "errors", "timefmt", "config", "retention_policy"}
# What the read side and the HTTP layer are made of.
READING = ("history", "grafana", "ngsild", "export", "ui")
HTTP = ("api", "app", "cli", "httpserver", "security", "demo", "metrics")
# Geometry primitives (parsing GeoJSON, extents, geodesic distance) sit
# beside the vocabulary; geo-*queries* are on the read side.
GEO_QUERIES = ("geo.filter", "geo.matching", "geo.masks")


GRAPH = import_graph()


def _under(name: str, prefixes) -> bool:
    short = name.removeprefix("tsdb_service.")
    return any(short == p or short.startswith(p + ".") for p in prefixes)


def _offenders(sources, forbidden, allowed=()) -> list[str]:
    return sorted(
        f"{module} -> {target}"
        for module, targets in GRAPH.items()
        if _under(module, sources) and not _under(module, allowed)
        for target in targets
        if _under(target, forbidden)
    )


def test_the_graph_was_read():
    assert {"tsdb_service.core.query", "tsdb_service.storage.base", "tsdb_service.parse.request_context"} <= set(GRAPH)


def test_the_vocabulary_imports_only_itself():
    offenders = sorted(
        f"{module} -> {target}"
        for module, targets in GRAPH.items()
        if _under(module, VOCABULARY)
        for target in targets
        if target != "tsdb_service" and not _under(target, VOCABULARY)
    )
    assert offenders == []


@pytest.mark.parametrize(
    ("layer", "above"),
    [
        (("ngsi",), ("storage", *READING, *HTTP, *GEO_QUERIES)),
        (("storage",), (*READING, *HTTP, *GEO_QUERIES)),
        (("history", "geo", "export"), HTTP),
    ],
    ids=["parsing", "storage", "reading"],
)
def test_no_import_goes_back_up(layer, above):
    # export.commands is the `tsdb-service export` command: part of the CLI.
    assert _offenders(layer, above, allowed=("export.commands",)) == []
