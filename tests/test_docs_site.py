"""The documentation site and the README, the front door.

``mkdocs build --strict`` runs in the README's test command (and ``.ci/run``);
these tests check that it would fail on what it is there to catch (a broken
link, a missing anchor, a page left out of the navigation), that the README
stays a short front door that opens with the two commands, that every file
the pages name exists, and that the Python client example returns data
against a live demo feed.
"""

from __future__ import annotations

import asyncio
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest
from markdown.extensions.toc import slugify

ROOT = Path(__file__).resolve().parent.parent
DOCS = ROOT / "docs"
README = (ROOT / "README.md").read_text()
MKDOCS = [sys.executable, "-m", "mkdocs"]


def _fences(text: str) -> list[tuple[str, str]]:
    """``(language, body)`` of every fenced code block, in order."""
    return re.findall(r"(?ms)^```(\w*)\n(.*?)^```", text)


def test_the_readme_opens_with_the_two_commands():
    first, second = [body.strip() for _, body in _fences(README)[:2]]
    assert README.index("```sh") < README.index("\n## "), "the commands come before anything else"
    assert first.startswith("python3 -m venv .venv && .venv/bin/pip install -q -e '.[test]'")
    assert first.endswith("&& .venv/bin/tsdb-service demo")
    assert ".venv/bin/mkdocs build --strict" in second and second.endswith(".venv/bin/python -m pytest -q -n 2")
    ci = (ROOT / ".ci" / "run").read_text().strip().splitlines()[-1]
    assert ci == second, "the CI script runs exactly the README's test command"


def test_the_readme_is_a_front_door():
    assert len(README.splitlines()) <= 200
    for section in ("## Connect your Orion", "## What it does", "## Documentation"):
        assert section in README


def _links(text: str) -> list[str]:
    return re.findall(r"\]\(([^)\s]+)\)", text)


def _anchors(page: Path) -> set[str]:
    text = re.sub(r"(?ms)^```.*?^```", "", page.read_text())
    return {slugify(re.sub(r"`", "", h), "-") for h in re.findall(r"(?m)^#{1,6} (.+)$", text)}


def test_the_readme_links_resolve():
    for link in _links(README):
        if link.startswith(("http://", "https://")):
            continue
        path, _, anchor = link.partition("#")
        target = ROOT / path
        assert target.exists(), link
        if anchor:
            assert anchor in _anchors(target), link


def test_every_page_is_reachable_and_built():
    nav = (ROOT / "mkdocs.yml").read_text()
    pages = sorted(p.name for p in DOCS.glob("*.md"))
    assert pages and all(f": {name}" in nav for name in pages), "strict mode refuses a page left out of nav"
    for name in (
        "getting-started.md",
        "orion.md",
        "ingest.md",
        "quantumleap.md",
        "ngsi-ld.md",
        "geo.md",
        "grafana.md",
        "explorer.md",
        "operations.md",
        "security.md",
        "postgresql.md",
        "architecture.md",
        "benchmarks.md",
        "experiment-log.md",
        "changelog.md",
    ):
        assert name in pages, name


@pytest.mark.parametrize(
    ("breakage", "says"),
    [
        ("link", "is not found among documentation files"),
        ("anchor", "does not contain an anchor"),
        ("page", 'are not included in the "nav" configuration'),
    ],
)
def test_a_strict_build_fails_on_broken_links(tmp_path, breakage, says):
    site = tmp_path / "project"
    shutil.copytree(DOCS, site / "docs")
    shutil.copy(ROOT / "mkdocs.yml", site / "mkdocs.yml")
    geo = site / "docs" / "geo.md"
    if breakage == "link":
        geo.write_text(geo.read_text() + "\nSee [the moved page](no-such-page.md).\n")
    elif breakage == "anchor":
        geo.write_text(geo.read_text() + "\nSee [a section](orion.md#no-such-section).\n")
    else:
        (site / "docs" / "forgotten.md").write_text("# Forgotten\n")
    done = subprocess.run(
        [*MKDOCS, "build", "--strict", "-f", str(site / "mkdocs.yml"), "-d", str(tmp_path / "out")],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode != 0 and says in done.stderr + done.stdout, done.stderr


# Paths the pages name in code spans: they must exist in the repository.
_NAMED = re.compile(
    r"`((?:tsdb_service|tests|benchmarks|docker|dashboards|migrations|notifications|queries)/[^`\s*<>{}]*)`"
)


def test_the_pages_name_only_files_that_exist():
    missing = []
    for page in [*DOCS.glob("*.md"), ROOT / "README.md", ROOT / "benchmarks" / "README.md"]:
        for name in _NAMED.findall(page.read_text()):
            path = name.split("::")[0].rstrip("/.,:;")
            if path.startswith("benchmarks/results"):
                continue  # the harnesses' output, git-ignored
            if not (ROOT / path).exists():
                missing.append(f"{page.name}: {name}")
    assert missing == []


def test_the_ngsi_ld_curl_example_says_globoff():
    page = (DOCS / "ngsi-ld.md").read_text()
    for _, body in _fences(page):
        for line in body.splitlines():
            if line.startswith("curl") and "coordinates=[" in line:
                assert line.startswith("curl -g "), line


@pytest.fixture(scope="module")
def fed_service(tmp_path_factory):
    from tests.grafana_fixtures import feed_live
    from tests.support.server import ServerProcess

    server = ServerProcess(tmp_path_factory.mktemp("docs") / "demo.duckdb").start()
    try:
        asyncio.run(feed_live(server.url, int(time.time() * 1000)))
        yield server
    finally:
        server.terminate()


def test_the_python_client_example_returns_data(fed_service, tmp_path, monkeypatch):
    """Its dates were fixed in 2025, so against the demo's live data it returned empty frames."""
    page = (DOCS / "quantumleap.md").read_text()
    section = page[page.index("## Python client") :]
    code = next(body for lang, body in _fences(section) if lang == "python")
    monkeypatch.chdir(tmp_path)
    scope: dict = {}
    exec(compile(code.replace("http://localhost:8668", fed_service.url), "quantumleap.md", "exec"), scope)
    for name in ("entities", "speed", "recent", "per_minute", "obstacles", "samples"):
        assert len(scope[name]) > 0, f"{name} is empty"
    assert (tmp_path / "mower.csv").stat().st_size > 0
