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
import subprocess
import warnings
from collections.abc import Callable, Iterator

import pytest

from tests.support.notify import post_notification
from tsdb_service.app import create_app
from tsdb_service.core.config import Settings

# Fixture modules every test module can use, without importing them.
pytest_plugins = ["tests.grafana_fixtures"]

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
    temporary directory and a free port), stopped at the end. Not durable
    (no fsync): it is thrown away, and the tests crash the service, never
    the cluster."""
    from tests.support.pg_cluster import PgCluster, find_bin

    if not (find_bin("initdb") and find_bin("pg_ctl")):
        pytest.skip("PostgreSQL server binaries (initdb, pg_ctl) are not installed")
    for attempt in range(3):  # each xdist worker starts one: another may take the free port first
        cluster = PgCluster(durable=False)
        try:
            cluster.start()
            break
        except subprocess.CalledProcessError:
            cluster.stop()
            if attempt == 2:
                raise
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


class _PgDatabases:
    """``make(name)`` → a fresh, empty database on the suite's cluster.

    A database a test gave back (``release``) is emptied, its ``public``
    schema dropped and created again as a new database has it (owner,
    privileges, comment), and handed out next: what the service finds is
    the same empty database, in a few milliseconds instead of a copy of
    template1 (7 MB, ~0.1-0.3 s here) plus its deletion at the end. A
    database something is still connected to is never handed out again."""

    def __init__(self, cluster) -> None:
        self.cluster = cluster
        self.counter = itertools.count(1)
        self.emptied: list[str] = []

    def __call__(self, name: str = "db") -> str:
        if self.emptied:
            return self.emptied.pop()
        safe = re.sub(r"[^a-z0-9_]", "_", name.lower())[:40]
        return self.cluster.database(f"{safe}_{next(self.counter)}")

    def release(self, url: str) -> None:
        import psycopg

        try:
            with psycopg.connect(url, autocommit=True) as conn:
                others = "SELECT count(*) FROM pg_stat_activity WHERE datname = current_database() AND pid <> %s"
                if conn.execute(others, [conn.info.backend_pid]).fetchone()[0]:
                    return
                conn.execute("SET lock_timeout = '5s'")
                with conn.transaction():
                    conn.execute("DROP SCHEMA public CASCADE")
                    conn.execute("CREATE SCHEMA public AUTHORIZATION pg_database_owner")
                    conn.execute("GRANT USAGE ON SCHEMA public TO PUBLIC")
                    conn.execute("COMMENT ON SCHEMA public IS 'standard public schema'")
        except psycopg.Error:
            return
        self.emptied.append(url)


@pytest.fixture(scope="session")
def pg_databases(pg_cluster) -> _PgDatabases:
    """The cluster's databases for the whole run, whatever the order of the
    backends (``store_url_factory`` is made again at each change of backend)."""
    return _PgDatabases(pg_cluster)


@pytest.fixture(scope="session")
def store_url_factory(backend, tmp_path_factory, request) -> Callable[[str], str]:
    """``make(name)`` → a fresh, empty store location on the backend under test."""
    if backend == "postgresql":
        return request.getfixturevalue("pg_databases")

    def make(name: str = "db") -> str:
        return str(tmp_path_factory.mktemp(name) / "tsdb.duckdb")

    return make


@pytest.fixture
def store_url(store_url_factory) -> Iterator[str]:
    """A fresh, empty store for one test (on PostgreSQL, emptied afterwards for the next one)."""
    url = store_url_factory("db")
    yield url
    if isinstance(store_url_factory, _PgDatabases):
        store_url_factory.release(url)


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


@pytest.fixture(scope="session")
def notify():
    """``notify(client, body, headers)``: POST a notification, assert 200."""
    return post_notification


# -- pytest-xdist: what runs together ----------------------------------------------------------


def _work_unit(nodeid: str) -> str:
    """A test module on one backend (``tests/test_x.py[duckdb]``), or the module
    alone for tests that take no backend. Modules that share a session
    fixture share a unit, so the fixture is set up once."""
    path, _, name = nodeid.partition("::")
    stem = path.rsplit("/", 1)[-1].removesuffix(".py")
    if stem in _BOTH_BACKENDS:
        return path
    module = _SHARED_UNITS.get(stem, path)
    params = name.partition("[")[2].rstrip("]").split("-")
    backends = [b for b in _backends() if b in params]
    return f"{module}[{backends[0]}]" if len(backends) == 1 else module


# Modules whose backends run together: the fuzzing replays on the second
# backend the cases generated for the first (generating is most of its time).
_BOTH_BACKENDS = {"test_fuzz_schemathesis"}
# The modules of the loaded Grafana server (``grafana_server``, session scope).
_SHARED_UNITS = dict.fromkeys(
    ("test_grafana_contract", "test_grafana_contract_ld", "test_grafana_simplejson", "test_grafana_schema"), "grafana"
)


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_make_scheduler(config, log):
    """With ``-n N`` (and no other ``--dist``): each worker takes whole units
    (see ``_work_unit``) in the collection's order, which pytest sorts by
    backend. A worker then runs the DuckDB tests, then the PostgreSQL ones,
    then those that take no backend: the session fixtures of one backend
    (its store factory, the loaded Grafana server) are set up once per
    worker, and each module's module fixtures once. xdist's default would
    send single tests: module fixtures (a loaded store, a served process)
    set up on every worker, and the backend changing back and forth."""
    if config.getoption("dist") != "load":
        return None
    from xdist.scheduler import LoadScopeScheduling

    class _ByUnit(LoadScopeScheduling):
        def _split_scope(self, nodeid: str) -> str:
            return _work_unit(nodeid)

    config.option.loadscopereorder = False  # keep pytest's order: one change of backend per worker
    return _ByUnit(config, log)


def pytest_terminal_summary(terminalreporter) -> None:
    """The ETSI conformance figure (``test_ngsild_etsi_suite`` records it as
    the property ``etsi``) as the last lines of pytest's output, whatever
    the verbosity, with ``-n`` too (properties travel with the reports)."""
    reports = [r for kind in ("passed", "failed") for r in terminalreporter.stats.get(kind, ())]
    lines = [value for r in reports if r.when == "call" for name, value in r.user_properties if name == "etsi"]
    for line in lines:
        terminalreporter.write_line(line)
