"""SQL of our database lives in storage only: the import graph and the calls that say so.

Routes, the read side (history, geo, grafana, ngsild, export) and the
commands see the seams (``read``, ``write``, ``storage.store``), never the
SQL renderers (``storage.sql``) or a backend package,
and never reach into a querier's private ``_fetch`` / ``_batches`` or its
``dialect``. Checked on the source (AST), so a lazy import inside a function
counts too.

One package outside storage holds SQL: the QuantumLeap importer
(``commands.quantumleap``), whose reader reads QuantumLeap's tables and whose
layout writes them for the tests. That SQL is another service's database,
not ours: like an HTTP client of another API it belongs with the command
that uses it, and with its own ``Dialect`` (which QuantumLeap backend wrote
the tables). It may import from storage only the one helper that quotes
identifiers (``storage.sql.dialect.quote_ident``), never a renderer of our
tables or a backend.
"""

from __future__ import annotations

import ast
from pathlib import Path

from tests.support.imports import PACKAGE, module_imports

RENDERERS = ("tsdb_service.storage.sql",)
BACKENDS = ("tsdb_service.storage.duckdb", "tsdb_service.storage.postgres")
PRIVATE_READS = ("_fetch", "_batches")
FOREIGN_SQL = "commands/quantumleap"  # SQL of QuantumLeap's database (see above)
QUOTING = {"tsdb_service.storage.sql.dialect", "tsdb_service.storage.sql.dialect.quote_ident"}


def _outside_storage() -> list[Path]:
    return [p for p in sorted(PACKAGE.rglob("*.py")) if "storage" not in p.relative_to(PACKAGE).parts[:1]]


def _foreign_sql(path: Path) -> bool:
    return path.relative_to(PACKAGE).as_posix().startswith(FOREIGN_SQL + "/")


def _within(name: str, modules) -> bool:
    """``name`` is one of ``modules`` or something inside one."""
    return any(name == m or name.startswith(m + ".") for m in modules)


def test_only_storage_imports_the_sql_renderers_and_backends():
    found = {}
    for path in _outside_storage():
        bad = {n for n in module_imports(path) if _within(n, (*RENDERERS, *BACKENDS))}
        if _foreign_sql(path):
            bad -= QUOTING
        if bad:
            found[str(path.relative_to(PACKAGE))] = sorted(bad)
    assert found == {}


def test_the_checks_see_imports_of_every_shape():
    """The helper itself: relative, absolute and lazy imports all count."""
    seen = module_imports(PACKAGE / "storage" / "__init__.py")
    assert "tsdb_service.storage.duckdb.store" in seen  # a lazy ``from .duckdb.store import``
    assert module_imports(PACKAGE / "storage" / "duckdb" / "querier.py") >= {"tsdb_service.storage.sql"}


def test_nothing_outside_storage_reaches_into_a_querier():
    """No ``x._fetch`` / ``x._batches`` on another object (a class's own
    ``self._fetch``, such as the JSON-LD context loader's HTTP fetch, is its
    business) and no ``.dialect``: SQL is rendered and run in storage only
    (the QuantumLeap reader's ``dialect`` names QuantumLeap's backend)."""
    found = []
    for path in _outside_storage():
        for node in ast.walk(ast.parse(path.read_text())):
            if not isinstance(node, ast.Attribute):
                continue
            on_self = isinstance(node.value, ast.Name) and node.value.id == "self"
            ours = node.attr == "dialect" and not _foreign_sql(path)  # QuantumLeap's is its own
            if ours or (node.attr in PRIVATE_READS and not on_self):
                found.append(f"{path.relative_to(PACKAGE)}:{node.lineno} .{node.attr}")
    assert found == []


def test_the_quantumleap_importer_quotes_with_our_helper():
    """The allowance above is used, and only for quoting: the reader and the
    layout quote QuantumLeap's identifiers with ``quote_ident``."""
    for name in ("reader.py", "layout.py"):
        seen = module_imports(PACKAGE / FOREIGN_SQL / name)
        assert {n for n in seen if _within(n, RENDERERS)} == QUOTING
