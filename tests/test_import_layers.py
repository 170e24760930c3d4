"""The import graph is the house the folders show (docs: Architecture):

    core                                  the vocabulary: model, queries, errors, settings
    geo, usecases                         geometry primitives; the three use cases' data
    parse, broker                         notifications and requests parsed; Orion subscriptions
    read, write                           the two seams
    storage, history                      the backends behind the seams; history over the read seam
    http                                  the HTTP kit every feature leans on
    security, ingest, faces.*             who may call; notifications in; each API out
    telemetry, demo, commands             metrics wired to a store; the demo's simulators; copy, imports
    app, cli                              the application factory and the command line

Every package may import only the packages its row allows, so a new import
that goes up, or sideways between two faces, fails here with the module and
what it imported. Read from the source with ``ast`` (no import side effects).
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

from tests.support.imports import import_graph

SEAMS = {"core", "geo", "parse", "read", "write"}
ALLOWED: dict[str, set[str]] = {
    "core": set(),
    "geo": {"core"},
    "usecases": {"core"},
    "parse": {"core", "geo"},
    "broker": {"core", "usecases"},
    "read": {"core"},
    "write": {"core", "parse"},
    "storage": SEAMS,
    "history": {"core", "geo", "parse", "read"},
    "http": {"core", "parse", "read", "write"},
    "security": {"core", "http"},
    "ingest": {"core", "parse", "write", "http"},
    "faces": {*SEAMS, "usecases", "broker", "history", "http"},
    "telemetry": {"core", "parse", "write", "storage"},
    "demo": {"core", "usecases", "broker"},
    "commands": {*SEAMS, "storage"},
    "client": set(),
}
TOP = {"app", "cli", "__main__"}  # may import anything below them

GRAPH = import_graph()


def part(module: str) -> str:
    """``tsdb_service.faces.ngsild.fetch`` → ``faces.ngsild``; ``tsdb_service.storage.sql.dialect`` → ``storage``."""
    names = module.split(".")[1:]
    if not names:
        return ""
    if names[0] == "faces" and len(names) > 1:
        return f"faces.{names[1]}"
    return names[0]


def rule_of(p: str) -> str:
    return "faces" if p.startswith("faces.") else p


def edges() -> list[tuple[str, str, str, str]]:
    """(module, target, module's part, target's part) for every import between two parts."""
    modules = set(GRAPH)
    out = []
    for module, targets in GRAPH.items():
        for target in targets:
            if target in modules and target != "tsdb_service" and part(module) != part(target):
                out.append((module, target, part(module), part(target)))
    return out


def test_the_graph_was_read():
    assert {"tsdb_service.core.query", "tsdb_service.storage.store", "tsdb_service.parse.request_context"} <= set(GRAPH)


def test_every_package_has_a_rule():
    parts = {rule_of(part(m)) for m in GRAPH} - {""}
    assert parts - set(ALLOWED) - TOP == set()


@pytest.mark.parametrize("package", sorted(ALLOWED))
def test_no_import_goes_up_or_sideways(package):
    offenders = sorted(
        f"{module} -> {target}"
        for module, target, source, dest in edges()
        if rule_of(source) == package and rule_of(dest) not in ALLOWED[package] and dest not in ALLOWED[package]
    )
    assert offenders == []


def test_no_face_imports_another_face():
    offenders = sorted(
        f"{module} -> {target}"
        for module, target, source, dest in edges()
        if source.startswith("faces.") and dest.startswith("faces")
    )
    assert offenders == []


def test_routes_see_only_the_seams():
    """Neither a face nor ingest reaches a backend: they get the store as the
    seams (``http.store.store_of``)."""
    offenders = sorted(
        f"{module} -> {target}"
        for module, target, source, dest in edges()
        if rule_of(source) in {"faces", "ingest", "http", "history"} and dest in {"storage", "telemetry"}
    )
    assert offenders == []


WRITE_MACHINERY = {"tsdb_service.write.committer", "tsdb_service.write.logged", "tsdb_service.write.log"}


def reached(module: str) -> set[str]:
    """Every module ``module`` imports, directly or through others (lazy imports too)."""
    seen: set[str] = set()
    todo = [module]
    while todo:
        name = todo.pop()
        if name in seen or name not in GRAPH:
            continue
        seen.add(name)
        todo.extend(GRAPH[name])
    return seen


def test_the_lowest_sql_reaches_no_write_machinery():
    """``storage.sql`` and the columns it reads sit under the writers: they
    reach neither the group committer nor the ingest log, not even through a
    module they share with the writers (``storage.committing`` wires those)."""
    lowest = [m for m in GRAPH if m.startswith("tsdb_service.storage.sql") or m == "tsdb_service.storage.columns"]
    offenders = {m: sorted(reached(m) & WRITE_MACHINERY) for m in lowest if reached(m) & WRITE_MACHINERY}
    assert lowest and offenders == {}


def test_tests_share_helpers_through_support_only():
    """A test module imports helpers from ``tests/support/`` (or a fixture
    module), never from another test module or ``conftest``: moving or
    deleting a test must not break others."""
    tests = Path(__file__).resolve().parent
    offenders = []
    for path in sorted(tests.glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.module:
                tail = node.module.removeprefix("tests.")
                if node.module.startswith("tests.") and (tail.startswith("test_") or tail == "conftest"):
                    offenders.append(f"{path.name} imports {node.module}")
    assert offenders == []
