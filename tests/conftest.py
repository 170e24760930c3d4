"""Fixtures shared by the whole suite, backend-neutral.

Tests never open a database by path themselves: they ask ``store_url`` (or
``store_url_factory`` for several) and ``app_factory``. Today those are
DuckDB files in a temporary directory; parametrizing ``store_url_factory``
over PostgreSQL URLs runs the same tests against PostgreSQL.
"""

from __future__ import annotations

import contextlib
import itertools
import os
import re
import warnings
from collections.abc import Callable, Iterator

import pytest

from tsdb_service.app import create_app
from tsdb_service.core.config import Settings

with warnings.catch_warnings():
    warnings.simplefilter("ignore")  # starlette's note about httpx2
    from fastapi.testclient import TestClient


class StoreClient(TestClient):
    """A test client after whose writes the store has applied them too.

    A notification is acknowledged once it is in the ingest log and applied
    to the database just behind (``write.logged``); reads through the API
    wait for it. Tests that look into the store directly (its querier, its
    tables) see what the API would: every write request syncs the store."""

    def request(self, method, url, *args, **kwargs):
        response = super().request(method, url, *args, **kwargs)
        store = getattr(self.app.state, "store", None)
        if method.upper() not in ("GET", "HEAD", "OPTIONS") and store is not None and hasattr(store, "sync"):
            with contextlib.suppress(Exception):  # a store that cannot catch up now says so to the next read
                store.sync()
        return response


def _backends() -> list[str]:
    """Both backends unless TSDB_TEST_BACKENDS narrows it (e.g. "duckdb")."""
    wanted = os.environ.get("TSDB_TEST_BACKENDS", "duckdb,postgresql")
    return [b.strip() for b in wanted.split(",") if b.strip()]


@pytest.fixture(scope="session")
def pg_cluster():
    """A private PostgreSQL cluster for the whole run (initdb + pg_ctl on a
    temporary directory and a free port), stopped at the end."""
    from pg_cluster import PgCluster, find_bin

    if not (find_bin("initdb") and find_bin("pg_ctl")):
        pytest.skip("PostgreSQL server binaries (initdb, pg_ctl) are not installed")
    cluster = PgCluster().start()
    try:
        yield cluster
    finally:
        cluster.stop()


@pytest.fixture(scope="session")
def mosquitto(tmp_path_factory):
    """A private MQTT broker for the whole run (Debian's mosquitto on a free
    port, installed when missing and we are root; skipped otherwise)."""
    from tests.support.mosquitto import broker

    started = broker(tmp_path_factory.mktemp("mosquitto"))
    try:
        yield started
    finally:
        started.close()


@pytest.fixture(scope="session", params=_backends())
def backend(request) -> str:
    return request.param


@pytest.fixture(scope="session")
def store_url_factory(backend, tmp_path_factory, request) -> Callable[[str], str]:
    """``make(name)`` → a fresh, empty store location on the backend under test."""
    if backend == "postgresql":
        cluster = request.getfixturevalue("pg_cluster")
        counter = itertools.count(1)

        def make_pg(name: str = "db") -> str:
            safe = re.sub(r"[^a-z0-9_]", "_", name.lower())[:40]
            return cluster.database(f"{safe}_{next(counter)}")

        return make_pg

    def make(name: str = "db") -> str:
        return str(tmp_path_factory.mktemp(name) / "tsdb.duckdb")

    return make


@pytest.fixture
def store_url(store_url_factory) -> str:
    return store_url_factory("db")


@pytest.fixture(scope="session")
def app_factory() -> Callable[..., object]:
    """``make(store_url, **settings)`` → an app (not started)."""

    def make(url: str, **overrides):
        return create_app(Settings(db=url, **overrides))

    return make


@pytest.fixture(scope="session")
def client_factory(app_factory):
    """``with client_factory(url) as client:`` → a started in-process app."""

    def make(url: str, **overrides) -> TestClient:
        return StoreClient(app_factory(url, **overrides))

    return make


@pytest.fixture
def client(client_factory, store_url) -> Iterator[TestClient]:
    with client_factory(store_url) as c:
        yield c


def post_notification(client, body: dict, headers: dict | None = None):
    """POST one notification; fail the test unless it was stored."""
    response = client.post("/v2/notify", json=body, headers={"Content-Type": "application/json", **(headers or {})})
    assert response.status_code == 200, response.text
    return response


@pytest.fixture(scope="session")
def notify():
    """``notify(client, body, headers)``: POST a notification, assert 200."""
    return post_notification
