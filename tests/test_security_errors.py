"""A 500 names no internal class: the client gets a neutral body and a
request id, the operator finds the details under that id in the log.
``/version`` and ``/health`` say only what an operator needs."""

from __future__ import annotations

import logging
import re
import warnings

import pytest

from tsdb_service.ingest import http_notify as notify_module

with warnings.catch_warnings():
    warnings.simplefilter("ignore")
    from fastapi.testclient import TestClient


class SecretInternalFault(Exception):
    """An internal class whose name must not reach a client."""


def _explode(*_args, **_kwargs):
    raise SecretInternalFault("internal detail /var/lib/tsdb")


def _boom():
    _explode()


@pytest.fixture
def embedded_db(tmp_path) -> str:
    """Error rendering happens above storage: one backend suffices there."""
    return str(tmp_path / "tsdb.duckdb")


def _request_id(body: dict) -> str:
    match = re.search(r"request id ([0-9a-f]{16,32})", body["description"])
    assert match, body
    return match.group(1)


def _assert_neutral(response) -> str:
    assert response.status_code == 500
    body = response.json()
    assert set(body) == {"error", "description"} and body["error"] == "InternalError"
    assert "SecretInternalFault" not in response.text and "/var/lib" not in response.text
    return _request_id(body)


def test_framework_500_is_neutral_and_traceable(app_factory, embedded_db, caplog):
    app = app_factory(embedded_db)
    app.add_api_route("/boom", _boom, methods=["GET"])
    with TestClient(app, raise_server_exceptions=False) as client, caplog.at_level(logging.ERROR):
        response = client.get("/boom")
    rid = _assert_neutral(response)
    assert response.headers["x-request-id"] == rid
    logged = [r for r in caplog.records if rid in r.getMessage()]
    assert logged and logged[0].exc_info and logged[0].exc_info[0] is SecretInternalFault


def test_notification_500_is_the_same_neutral_body(client, monkeypatch, caplog):
    monkeypatch.setattr(notify_module, "parse_notification", _explode)
    with caplog.at_level(logging.ERROR):
        response = client.post("/v2/notify", json={"data": []})
    rid = _assert_neutral(response)
    assert any(rid in r.getMessage() and r.exc_info for r in caplog.records)


def test_notification_500_answers_as_the_framework_does(app_factory, embedded_db, monkeypatch):
    """The notify fast path runs in front of the framework, so it renders its
    own 500: the same body (shape and text), content type and request id
    header as the framework's handler gives any other route."""
    monkeypatch.setattr(notify_module, "parse_notification", _explode)
    app = app_factory(embedded_db)
    app.add_api_route("/boom", _boom, methods=["GET"])
    with TestClient(app, raise_server_exceptions=False) as client:
        responses = [client.get("/boom"), client.post("/v2/notify", json={"data": []})]
    answers = []
    for response in responses:
        rid = _assert_neutral(response)
        assert response.headers["x-request-id"] == rid
        body = {key: text.replace(rid, "<id>") for key, text in response.json().items()}
        answers.append((response.headers["content-type"], body))
    assert answers[0] == answers[1]


def test_request_ids_differ(app_factory, embedded_db):
    app = app_factory(embedded_db)
    app.add_api_route("/boom", _boom, methods=["GET"])
    with TestClient(app, raise_server_exceptions=False) as client:
        ids = {_assert_neutral(client.get("/boom")) for _ in range(3)}
    assert len(ids) == 3


def test_version_says_the_version_only(client_factory, embedded_db):
    with client_factory(embedded_db) as client:
        body = client.get("/version").json()
    assert set(body) == {"version"}


@pytest.mark.parametrize("ingested", [False, True])
def test_health_has_no_internal_counters(client, notify, ingested):
    if ingested:
        notify(client, {"data": [{"id": "e", "type": "T", "v": {"type": "Number", "value": 1}}]})
    response = client.get("/health")
    assert response.status_code == 200
    assert response.headers["content-type"].startswith("application/health+json")
    body = response.json()
    assert body["status"] == "pass"
    assert set(body) <= {"status", "output"}
