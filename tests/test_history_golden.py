"""Golden tests of the history API: notifications in, exact JSON out.

The corpus lives in ``tests/golden``:

* ``notifications/<dataset>/*.json``: ``{"headers", "body"}`` posted in file
  name order to ``POST /v2/notify`` of a fresh store;
* ``cases/*.json``: ``{"dataset", "mode", "cases": [{"name", "method",
  "path", "headers", "body", "status", "response"}]}``. ``mode`` is
  ``independent`` (read-only cases, one test each, sharing one loaded store
  per dataset) or ``sequence`` (one test running the steps in order on its
  own store, for deletes).

Regenerate expected answers with ``UPDATE_GOLDEN=1 pytest
tests/test_history_golden.py``, then review the diff by hand: the files are
the specification.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

GOLDEN = Path(__file__).parent / "golden"
UPDATE = os.environ.get("UPDATE_GOLDEN") == "1"


def _case_files() -> list[Path]:
    return sorted((GOLDEN / "cases").glob("*.json"))


def _load(path: Path) -> dict:
    return json.loads(path.read_text(encoding="utf-8"))


def _independent_params():
    params = []
    for path in _case_files():
        doc = _load(path)
        if doc.get("mode", "independent") != "independent":
            continue
        for i, case in enumerate(doc["cases"]):
            params.append(pytest.param(path, i, doc["dataset"], id=f"{path.stem}:{case['name']}"))
    return params


def _sequence_params():
    return [
        pytest.param(path, id=path.stem)
        for path in _case_files()
        if _load(path).get("mode", "independent") == "sequence"
    ]


def load_dataset(client, name: str, notify) -> None:
    for path in sorted((GOLDEN / "notifications" / name).glob("*.json")):
        note = _load(path)
        notify(client, note["body"], note.get("headers"))


def perform(client, case: dict):
    method = case.get("method", "GET")
    headers = case.get("headers") or {}
    if case.get("body") is not None:
        response = client.request(method, case["path"], json=case["body"], headers=headers)
    else:
        response = client.request(method, case["path"], headers=headers)
    body = response.json() if response.content else None
    return response.status_code, body


def check(case: dict, status: int, body) -> None:
    if UPDATE:
        case["status"], case["response"] = status, body
        return
    assert (status, body) == (case["status"], case.get("response")), (
        f"{case.get('method', 'GET')} {case['path']}: got {status} {json.dumps(body, indent=1)[:3000]}"
    )


class _Datasets:
    """One loaded app per dataset, shared by the read-only cases."""

    def __init__(self, client_factory, store_url_factory, notify):
        self._make_client, self._make_url, self._notify = client_factory, store_url_factory, notify
        self._clients: dict[str, object] = {}

    def client(self, name: str):
        if name not in self._clients:
            client = self._make_client(self._make_url(f"golden-{name}"))
            client.__enter__()
            load_dataset(client, name, self._notify)
            self._clients[name] = client
        return self._clients[name]

    def close(self) -> None:
        for client in self._clients.values():
            client.__exit__(None, None, None)


@pytest.fixture(scope="module")
def datasets(client_factory, store_url_factory, notify):
    ds = _Datasets(client_factory, store_url_factory, notify)
    yield ds
    ds.close()


_documents: dict[Path, dict] = {}


def _document(path: Path) -> dict:
    if path not in _documents:
        _documents[path] = _load(path)
    return _documents[path]


@pytest.fixture(scope="module", autouse=True)
def _rewrite_golden():
    yield
    if UPDATE:
        for path, doc in _documents.items():
            path.write_text(json.dumps(doc, indent=2, ensure_ascii=False) + "\n", encoding="utf-8")


@pytest.mark.parametrize(("path", "index", "dataset"), _independent_params())
def test_golden(datasets, path: Path, index: int, dataset: str):
    case = _document(path)["cases"][index]
    status, body = perform(datasets.client(dataset), case)
    check(case, status, body)


@pytest.mark.parametrize("path", _sequence_params())
def test_golden_sequence(client_factory, store_url_factory, notify, path: Path):
    doc = _document(path)
    with client_factory(store_url_factory(f"golden-{path.stem}")) as client:
        load_dataset(client, doc["dataset"], notify)
        for case in doc["cases"]:
            status, body = perform(client, case)
            check(case, status, body)
