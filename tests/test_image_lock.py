"""The image installs from hash-locked requirements that agree with pyproject.toml.

``requirements.lock`` holds every runtime dependency, direct and transitive,
each pinned to one version with the hashes of its files, and
``requirements-build.lock`` the build backend; the Dockerfile installs them
with ``--require-hashes --no-deps`` (tests/test_containers.py checks the
instructions), so a build takes no version and no file the lock does not
name. ``sh docker/lock.sh`` regenerates both after a pin changes; until then
these tests fail and say which pin differs.
"""

from __future__ import annotations

import re
import tomllib
from importlib import metadata
from pathlib import Path

import pytest
from packaging.requirements import Requirement
from packaging.utils import canonicalize_name

ROOT = Path(__file__).resolve().parent.parent
PYPROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text())
LOCKS = {"requirements.lock": "runtime", "requirements-build.lock": "build"}


def entries(lock: str) -> list[tuple[Requirement, list[str]]]:
    """Each entry of a lock file: the requirement (name, ``==`` version,
    marker) and its hashes. Comments and continuation lines as pip reads them."""
    text = re.sub(r"\\\n", " ", (ROOT / lock).read_text())
    out = []
    for line in text.splitlines():
        line = line.split(" #", 1)[0].strip()
        if not line or line.startswith("#"):
            continue
        hashes = re.findall(r"--hash=(\S+)", line)
        out.append((Requirement(re.sub(r"\s*--hash=\S+", "", line).strip()), hashes))
    return out


def pinned(lock: str) -> dict[str, set[str]]:
    """Package name → the versions the lock pins for it (one, or one per marker)."""
    versions: dict[str, set[str]] = {}
    for requirement, _ in entries(lock):
        (spec,) = requirement.specifier
        versions.setdefault(canonicalize_name(requirement.name), set()).add(spec.version)
    return versions


def pyproject_pins(requirements: list[str]) -> dict[str, str]:
    out = {}
    for text in requirements:
        requirement = Requirement(text)
        (spec,) = requirement.specifier
        assert spec.operator == "==", f"pyproject.toml pins {text!r} loosely"
        out[canonicalize_name(requirement.name)] = spec.version
    return out


@pytest.mark.parametrize("lock", LOCKS)
def test_every_entry_is_one_version_with_hashes(lock):
    found = entries(lock)
    assert found, lock
    for requirement, hashes in found:
        (spec,) = requirement.specifier
        assert spec.operator == "==", requirement
        assert hashes and all(h.startswith("sha256:") and len(h) == 7 + 64 for h in hashes), requirement
        assert not requirement.extras, f"{requirement}: extras are resolved into entries of their own"


@pytest.mark.parametrize("lock", LOCKS)
def test_the_lock_says_how_to_regenerate_it(lock):
    assert "sh docker/lock.sh" in (ROOT / lock).read_text().split("\n", 3)[1]


def test_the_runtime_lock_pins_what_pyproject_pins():
    locked = pinned("requirements.lock")
    for name, version in pyproject_pins(PYPROJECT["project"]["dependencies"]).items():
        assert locked.get(name) == {version}, f"{name}: pyproject.toml {version}, requirements.lock {locked.get(name)}"


def test_the_build_lock_pins_the_build_backend():
    locked = pinned("requirements-build.lock")
    for name, version in pyproject_pins(PYPROJECT["build-system"]["requires"]).items():
        assert locked.get(name) == {version}, name


def test_the_lock_holds_the_services_dependencies_and_nothing_else():
    """The closure of the runtime requirements, as the packages installed here
    declare them, is what the lock installs on this platform (Linux, Python
    3.11): nothing missing (the image's build also runs ``pip check``), and no
    test or tool package on top."""
    applicable = {
        canonicalize_name(requirement.name)
        for requirement, _ in entries("requirements.lock")
        if requirement.marker is None or requirement.marker.evaluate()
    }
    assert needed(PYPROJECT["project"]["dependencies"]) == applicable, "sh docker/lock.sh"


def needed(requirements: list[str]) -> set[str]:
    """Every distribution ``requirements`` need, extras and markers applied."""
    names: set[str] = set()
    seen: set[str] = set()
    todo = [Requirement(text) for text in requirements]
    while todo:
        requirement = todo.pop()
        name = canonicalize_name(requirement.name)
        key = name + "".join(f"[{e}]" for e in sorted(requirement.extras))
        if key in seen:
            continue
        seen.add(key)
        names.add(name)
        environments = [{"extra": extra} for extra in requirement.extras] or [{"extra": ""}]
        for text in metadata.requires(name) or []:
            child = Requirement(text)
            if child.marker is None or any(child.marker.evaluate(env) for env in environments):
                todo.append(child)
    return names


def test_the_lock_tool_is_pinned_and_used():
    (uv,) = PYPROJECT["project"]["optional-dependencies"]["lock"]
    assert re.fullmatch(r"uv==\d+\.\d+\.\d+", uv)
    script = (ROOT / "docker" / "lock.sh").read_text()
    assert "uv pip compile pyproject.toml" in script and "--generate-hashes" in script and "--universal" in script
    assert "--output-file requirements.lock" in script and "--output-file requirements-build.lock" in script
