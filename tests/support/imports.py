"""What a module of the package imports, read from its source with ``ast``
(no import side effects; lazy imports inside functions count too). Shared
by the tests that pin the import graph."""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parent.parent.parent / "tsdb_service"


def module_name(path: Path) -> str:
    """``tsdb_service/storage/store.py`` → ``tsdb_service.storage.store``."""
    parts = list(path.relative_to(PACKAGE.parent).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def module_imports(path: Path) -> set[str]:
    """The ``tsdb_service`` modules ``path`` imports, and each imported name
    as ``module.name`` (so ``from . import x`` names submodule ``x`` too)."""
    module = module_name(path)
    package = module if path.name == "__init__.py" else module.rsplit(".", 1)[0]
    out: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - node.level + 1]
                target = ".".join([*base, node.module] if node.module else base)
            else:
                target = node.module or ""
            out.add(target)
            out.update(f"{target}.{alias.name}" for alias in node.names)
        elif isinstance(node, ast.Import):
            out.update(alias.name for alias in node.names)
    return {name for name in out if name.startswith("tsdb_service")}


def import_graph() -> dict[str, set[str]]:
    """Every module of the package → what it imports (``module_imports``)."""
    return {module_name(path): module_imports(path) for path in PACKAGE.rglob("*.py")}
