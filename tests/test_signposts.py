"""Signposts that cannot drift: every module, file and section a docstring,
comment or documentation page names exists, and the architecture page's
tables of read protocols and locks say what the code has.

A reader follows ``storage.sql.temporal`` or ``write/logged.py`` from a
docstring, or a lock from the architecture page, to the code; after a move
the name must move too, so the next move fails here instead of misleading
the reader. What counts as a name:

* a dotted name in backticks whose first part is a package or module of
  ``tsdb_service`` (or was one: old names must not linger), resolved from the
  package root or from any package inside it (``ngsild.params`` is
  ``faces.ngsild.params``), the parts past the module being attributes;
* a ``file.py`` (or ``dir/file.py``) name, resolved against the files of the
  repository (a path's tail must match);
* a README section a comment points at (the README is the front door: the
  sections it had moved to ``docs/``).
"""

from __future__ import annotations

import ast
import importlib
import io
import re
import tokenize
from collections.abc import Iterator
from functools import cache
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "tsdb_service"
DOCS = [*sorted((ROOT / "docs").glob("*.md")), ROOT / "README.md", ROOT / "benchmarks" / "README.md"]
SKIP_DIRS = {".venv", ".git", "site", "node_modules", "vendor", "__pycache__", "golden", "payloads", "results"}

# Package and module names the tree has had; a dotted name starting with one
# of them is a module reference (whether the name is still current or not).
FORMER_ROOTS = {
    "api",
    "ngsi",
    "budget",
    "config",
    "errors",
    "export",
    "grafana",
    "httpserver",
    "idpattern",
    "metrics",
    "model",
    "ngsild",
    "query",
    "rawpath",
    "retention_policy",
    "timefmt",
    "ui",
    "quantumleap",
    "operator",
}

FILE_EXTENSIONS = {
    "py",
    "md",
    "json",
    "jsonld",
    "yaml",
    "yml",
    "toml",
    "sql",
    "html",
    "js",
    "css",
    "txt",
    "csv",
    "parquet",
    "duckdb",
}

# Placeholders in examples, not names of files.
EXAMPLE_FILES = {"file.py", "dir/file.py", "module.py", "path/to/module.py", "tests/test_x.py"}

_DOTTED = re.compile(r"``?([A-Za-z_][A-Za-z0-9_]*(?:\.[A-Za-z_][A-Za-z0-9_]*)+)(?:\(\))?``?")
_PYFILE = re.compile(r"(?<![\w./-])((?:[\w.-]+/)*[\w-]+\.py)\b")
_README_SECTION = re.compile(r"README(?:'s|\u2019s)?[ ,]+(?:\*([^*]+)\*|\"([^\"]+)\")")


PROTOCOLS_HEADING = "### Reading"
LOCKS_HEADING = "## Caches and locks"


def markdown_table(page: Path, heading: str) -> list[list[str]]:
    """The body rows of the first table under ``heading``, as cells."""
    lines = page.read_text().splitlines()
    start = next(i for i, line in enumerate(lines) if line == heading or line.startswith(heading + " "))
    rows: list[list[str]] = []
    for line in lines[start + 1 :]:
        if line.startswith("#"):
            break
        if line.startswith("|"):
            rows.append([cell.strip() for cell in line.strip().strip("|").split("|")])
        elif rows:
            break
    return [row for row in rows[2:]]


def _python_files() -> list[Path]:
    found = []
    for base in (PACKAGE, ROOT / "tests", ROOT / "benchmarks"):
        found += [p for p in base.rglob("*.py") if not SKIP_DIRS & set(p.relative_to(ROOT).parts)]
    return sorted(found)


@cache
def _repo_files() -> tuple[str, ...]:
    files = []
    for p in ROOT.rglob("*"):
        rel = p.relative_to(ROOT)
        if p.is_file() and not SKIP_DIRS & set(rel.parts):
            files.append(rel.as_posix())
    return tuple(files)


def _prose_of(path: Path) -> Iterator[tuple[int, str]]:
    """(line, text) of every docstring and comment of a Python file."""
    source = path.read_text()
    tree = ast.parse(source)
    for node in ast.walk(tree):
        if isinstance(node, ast.Module | ast.ClassDef | ast.FunctionDef | ast.AsyncFunctionDef):
            docstring = ast.get_docstring(node, clean=False)
            if docstring is not None:
                yield node.body[0].lineno, docstring
    for token in tokenize.generate_tokens(io.StringIO(source).readline):
        if token.type == tokenize.COMMENT:
            yield token.start[0], token.string


def _prose() -> Iterator[tuple[str, int, str]]:
    for path in _python_files():
        for line, text in _prose_of(path):
            yield path.relative_to(ROOT).as_posix(), line, text
    for page in DOCS:
        for number, text in enumerate(page.read_text().splitlines(), 1):
            yield page.relative_to(ROOT).as_posix(), number, text


@cache
def _packages() -> tuple[str, ...]:
    """Every package of tsdb_service, dotted, the root as ''."""
    names = [""]
    for init in PACKAGE.rglob("__init__.py"):
        rel = init.parent.relative_to(PACKAGE)
        if rel.parts:
            names.append(".".join(rel.parts))
    return tuple(sorted(names))


@cache
def _roots() -> frozenset[str]:
    current = {p.stem if p.is_file() else p.name for p in PACKAGE.iterdir() if not p.name.startswith("_")}
    subpackages = {name.rsplit(".", 1)[-1] for name in _packages() if name}
    return frozenset({"tsdb_service", *current, *subpackages, *FORMER_ROOTS} - {"static"})


def _resolves(dotted: str) -> bool:
    parts = dotted.split(".")
    if parts[0] == "tsdb_service":
        return _resolves_under("", parts[1:])
    return any(_resolves_under(package, parts) for package in _packages())


def _resolves_under(package: str, parts: list[str]) -> bool:
    base = PACKAGE.joinpath(*package.split(".")) if package else PACKAGE
    for i in range(len(parts), 0, -1):
        path = base.joinpath(*parts[:i])
        if path.with_suffix(".py").is_file() or (path / "__init__.py").is_file():
            module = ".".join(["tsdb_service", *([package] if package else []), *parts[:i]])
            return _has_attributes(module, parts[i:])
    return False


@cache
def _module(name: str):
    return importlib.import_module(name)


def _has_attributes(module: str, attributes: list[str]) -> bool:
    if not attributes:
        return True
    obj = _module(module)
    for name in attributes:
        if not hasattr(obj, name):
            annotations = getattr(obj, "__annotations__", {})
            fields = getattr(obj, "__dataclass_fields__", {})
            slots = getattr(obj, "__slots__", ())
            return name in annotations or name in fields or name in slots
        obj = getattr(obj, name)
    return True


def _dotted_names() -> Iterator[tuple[str, int, str]]:
    roots = _roots()
    for where, line, text in _prose():
        for match in _DOTTED.finditer(text):
            name = match.group(1)
            if name.split(".", 1)[0] in roots and name.rsplit(".", 1)[-1] not in FILE_EXTENSIONS:
                yield where, line, name


def _file_names() -> Iterator[tuple[str, int, str]]:
    for where, line, text in _prose():
        for match in _PYFILE.finditer(text):
            if match.group(1) not in EXAMPLE_FILES:
                yield where, line, match.group(1)


def _file_exists(name: str, where: str) -> bool:
    if (ROOT / Path(where).parent / name).is_file():
        return True
    tail = "/" + name.lstrip("./")
    return any(("/" + f).endswith(tail) for f in _repo_files())


def test_every_dotted_module_name_resolves():
    missing = sorted({f"{where}:{line}: {name}" for where, line, name in _dotted_names() if not _resolves(name)})
    assert not missing, "names of modules (or their members) that do not exist:\n" + "\n".join(missing)


def test_every_python_file_name_exists():
    missing = sorted(
        {f"{where}:{line}: {name}" for where, line, name in _file_names() if not _file_exists(name, where)}
    )
    assert not missing, "file names that match no file of the repository:\n" + "\n".join(missing)


def test_readme_sections_named_in_comments_exist():
    headings = {h.strip().lower() for h in re.findall(r"^#+ (.+)$", (ROOT / "README.md").read_text(), re.M)}
    stale = []
    for where, line, text in _prose():
        for match in _README_SECTION.finditer(text):
            section = (match.group(1) or match.group(2)).strip().lower()
            if section not in headings:
                stale.append(f"{where}:{line}: README section {section!r}")
    assert not stale, "README sections that do not exist (point at the docs/ page instead):\n" + "\n".join(stale)


_DOC_REFERENCE = re.compile(r"\b((?:docs|benchmarks)/[\w-]+\.md|README\.md)(?:#([\w-]+)|,? \"([^\"]+)\")?")


def _anchor(heading: str) -> str:
    return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


def test_documentation_pages_and_sections_named_in_code_exist():
    wrong = []
    for where, line, text in _prose():
        if where.endswith(".md"):
            continue  # mkdocs --strict checks the pages' own links
        for match in _DOC_REFERENCE.finditer(text):
            page = ROOT / match.group(1)
            if not page.is_file():
                wrong.append(f"{where}:{line}: {match.group(1)}")
                continue
            section = match.group(2) or match.group(3)
            headings = re.findall(r"^#+ (.+)$", page.read_text(), re.M)
            if section and section.lower() not in {h.strip().lower() for h in headings} | {
                _anchor(h) for h in headings
            }:
                wrong.append(f"{where}:{line}: {match.group(1)} has no section {section!r}")
    assert not wrong, "documentation named in code that does not exist:\n" + "\n".join(wrong)


def _read_protocols() -> dict[str, set[str]]:
    import tsdb_service.read as read

    found = {}
    for name in ("SeriesCatalogue", "SampleReader", "LocationReader", "TemporalReader", "BulkReader", "BucketReader"):
        protocol = getattr(read, name)
        found[name] = {m for m in vars(protocol) if not m.startswith("_") and callable(getattr(protocol, m))}
    return found


def test_the_architecture_pages_protocol_table_lists_every_method():
    rows = markdown_table(ROOT / "docs" / "architecture.md", PROTOCOLS_HEADING)
    documented = {
        row[0].strip("` "): set(re.findall(r"`([a-z_]+)(?:\(|`)", row[1])) for row in rows if row[0].startswith("`")
    }
    assert documented == _read_protocols()


def test_every_lock_on_the_architecture_page_exists_where_it_says():
    rows = markdown_table(ROOT / "docs" / "architecture.md", LOCKS_HEADING)
    wrong = []
    for row in rows:
        where, lock = row[1], row[-1]
        files = re.findall(r"`([\w/]+\.py)`", where)
        names = re.findall(r"`(_?[A-Za-z_]+)`", lock)
        if not files or not names:
            continue
        text = "\n".join((PACKAGE / f).read_text() for f in files if (PACKAGE / f).is_file())
        wrong += [
            f"{row[0]}: {name} not in {', '.join(files)}" for name in names if not re.search(rf"\b{name}\b", text)
        ]
    assert not wrong, "\n".join(wrong)


@pytest.mark.parametrize("name", ["storage.sql.temporal", "ngsild.params", "core.query.TimeRange"])
def test_the_resolver_knows_good_names(name):
    assert _resolves(name)


@pytest.mark.parametrize("name", ["ngsi.request_context", "storage.temporal", "core.query.NoSuchThing"])
def test_the_resolver_refuses_stale_names(name):
    assert not _resolves(name)
