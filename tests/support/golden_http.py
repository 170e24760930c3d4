"""Golden answers over HTTP: every 200 JSON answer a test gets, compared in order.

A test module's answers live in one file, ``{test: [answer, ...]}``, keyed by
the test's name without the backend parameter, so DuckDB and PostgreSQL must
give the same answers (floats to 12 significant digits: the two databases
add up averages in different orders, which moves the last bits). ``UPDATE_GOLDEN=1`` records instead of comparing (the
second backend of a run is still compared with what the first recorded) and
rewrites the file at the end of the session; review the diff by hand.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import httpx

_BACKEND_ID = re.compile(r"(?<=\[)(duckdb|postgresql)(-|(?=\]))")


def canonical(value):
    """``value`` with every float rounded to 12 significant digits."""
    if isinstance(value, float):
        return float(f"{value:.12g}")
    if isinstance(value, list):
        return [canonical(v) for v in value]
    if isinstance(value, dict):
        return {k: canonical(v) for k, v in value.items()}
    return value


def _dump(answers: dict[str, list]) -> str:
    """JSON with one line per answer row, so that a diff shows the rows that changed."""

    def answer(value) -> str:
        if isinstance(value, list) and value:
            return "[\n" + ",\n".join("   " + json.dumps(v, ensure_ascii=False) for v in value) + "\n  ]"
        return json.dumps(value, ensure_ascii=False)

    tests = [
        f" {json.dumps(key)}: [\n" + ",\n".join("  " + answer(a) for a in values) + "\n ]"
        if values
        else f" {json.dumps(key)}: []"
        for key, values in answers.items()
    ]
    return "{\n" + ",\n".join(tests) + "\n}\n"


def golden_key(node_name: str) -> str:
    """``test_x[duckdb-a]`` -> ``test_x[a]``; ``test_x[postgresql]`` -> ``test_x``."""
    return _BACKEND_ID.sub("", node_name).replace("[]", "")


class GoldenFile:
    """The recorded answers of one test module."""

    def __init__(self, path: Path, update: bool):
        self.path, self.update = path, update
        self.answers: dict[str, list] = json.loads(path.read_text(encoding="utf-8")) if path.exists() else {}
        self.recorded: dict[str, list] = {}  # update mode: what this session recorded

    def expected(self, key: str) -> list | None:
        """The answers to compare with, or None to record them (update mode, first backend)."""
        if self.update:
            return self.recorded.get(key)
        assert key in self.answers, f"no golden answers for {key} in {self.path}: run with UPDATE_GOLDEN=1"
        return self.answers[key]

    def save(self) -> None:
        if self.update and self.recorded:
            answers = dict(sorted({**self.answers, **self.recorded}.items()))
            self.path.write_text(_dump(answers), encoding="utf-8")


class GoldenHttp:
    """An ``httpx.Client`` stand-in (``get``, ``post``, ``request``) that checks
    each 200 JSON answer against the next golden answer of the current test."""

    def __init__(self, client: httpx.Client, golden: GoldenFile, key: str):
        self._client, self._key = client, key
        self._expected = golden.expected(key)
        self._got: list = []
        if self._expected is None:
            golden.recorded[key] = self._got

    def request(self, method: str, url: str, **kwargs) -> httpx.Response:
        response = self._client.request(method, url, **kwargs)
        if response.status_code == 200 and response.headers.get("content-type", "").startswith("application/json"):
            self._check(f"{method} {url}", response.json())
        return response

    def get(self, url: str, **kwargs) -> httpx.Response:
        return self.request("GET", url, **kwargs)

    def post(self, url: str, **kwargs) -> httpx.Response:
        return self.request("POST", url, **kwargs)

    def _check(self, what: str, answer) -> None:
        answer, n = canonical(answer), len(self._got)
        if self._expected is not None:
            assert n < len(self._expected), f"{self._key}: answer {n} ({what}) is not in the golden file"
            assert answer == canonical(self._expected[n]), (
                f"{self._key}: answer {n} ({what}) differs from the golden file"
            )
        self._got.append(answer)

    def finish(self) -> None:
        """Every golden answer must have been asked for again."""
        if self._expected is not None:
            assert len(self._got) == len(self._expected), (
                f"{self._key}: {len(self._got)} answers, the golden file has {len(self._expected)}"
            )
