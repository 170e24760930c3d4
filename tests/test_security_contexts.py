"""Issue 27, the @context loader under attack: every hostile document,
redirect, trickling body and gzip bomb is served by a real local HTTP
server (``support.hostile``), and the service is the real app (in process,
or uvicorn in its own process where a real server matters).

By default a context on a loopback, private or link-local address is never
requested; ``TSDB_LD_CONTEXT_ALLOW`` (here ``http://127.0.0.1:``, as the
conformance run uses it) lets the tests reach their local servers, and then
the other defences (redirects, deadline, bytes, cache, immutability) are
what stands between the server and the attacker."""

from __future__ import annotations

import json
import threading
import time
import tracemalloc

import anyio
import httpx
import pytest

from tests.ngsild_fixtures import ENTITIES, H, error_type, ld_notify
from tests.support.hostile import Hostile
from tests.support.server import ServerProcess
from tsdb_service.faces.ngsild.context import CORE_CONTEXT_URL, ContextStore
from tsdb_service.http.outbound import FetchFailed, FetchPolicy, fetch, is_public

LOCAL = "http://127.0.0.1:"
QUERY = "/ngsi-ld/v1/temporal/entityOperations/query"
SENSOR = "urn:ngsi-ld:Sensor:1"
VICTIM_IRI = "https://victim.example/ns#temperature"
VICTIM = {"@context": {"temperature": VICTIM_IRI, "Sensor": "https://victim.example/ns#Sensor"}}


def link(url: str) -> dict[str, str]:
    return {"Link": f'<{url}>; rel="http://www.w3.org/ns/json-ld#context"; type="application/ld+json"'}


def ld_query(client, context, headers: dict | None = None, **extra):
    body = {"type": "Query", "entities": [{"type": "Sensor"}], "@context": context, **extra}
    return client.post(
        QUERY, content=json.dumps(body), headers={"Content-Type": "application/ld+json", **(headers or {})}
    )


def store_sensor(client, note: str = "ok") -> None:
    at = "2024-05-01T10:00:00Z"
    ld_notify(
        client,
        [
            {
                "id": SENSOR,
                "type": "Sensor",
                "temperature": {"type": "Property", "value": 21, "observedAt": at},
                "note": {"type": "Property", "value": note, "observedAt": at},
            }
        ],
    )


def contexts_of(client) -> ContextStore:
    return client.app.state.ngsild_contexts


@pytest.fixture
def hostile():
    with Hostile() as server:
        yield server


@pytest.fixture
def allowed(client_factory, store_url):
    """The app with the test servers' addresses allowed, on both backends."""
    with client_factory(store_url, ld_context_allow=LOCAL) as c:
        yield c


# --- SSRF: which addresses, which redirects, what the errors say ------------------------------


def test_addresses_that_are_not_public():
    for address in ("127.0.0.1", "10.1.2.3", "172.16.0.1", "192.168.1.1", "169.254.169.254", "100.64.0.1", "0.0.0.0"):
        assert not is_public(address), address
    for address in ("::1", "fe80::1", "fc00::1", "::ffff:127.0.0.1", "::ffff:169.254.169.254", "64:ff9b::a00:1"):
        assert not is_public(address), address
    assert not is_public("2002:7f00:1::")  # 6to4 around 127.0.0.1
    assert not is_public("224.0.0.1")  # multicast
    for address in ("8.8.8.8", "2001:4860:4860::8888", "::ffff:8.8.8.8"):
        assert is_public(address), address


def test_a_context_on_this_machine_is_never_requested_by_default(client, hostile):
    url = hostile.document("/ctx.jsonld", VICTIM)
    for target in (url, url.replace("127.0.0.1", "localhost"), f"http://[::1]:{hostile.port}/ctx.jsonld"):
        got = client.get(ENTITIES, params={"type": "Sensor"}, headers=link(target))
        assert got.status_code == 503 and error_type(got) == "LdContextNotAvailable", got.text
        assert got.json()["detail"] == f"context could not be loaded: {target}"
    assert hostile.hits == {}
    # user info cannot smuggle another host past an allowed prefix
    trick = f"http://127.0.0.1:@127.0.0.1:{hostile.port}/ctx.jsonld"
    assert ld_query(client, trick).status_code == 503
    assert hostile.hits == {}


def test_link_local_metadata_address_is_refused_before_any_connection(client):
    started = time.monotonic()
    got = client.get(ENTITIES, params={"type": "Sensor"}, headers=link("http://169.254.169.254/latest/"))
    assert (
        got.status_code == 503 and got.json()["detail"] == "context could not be loaded: http://169.254.169.254/latest/"
    )
    assert time.monotonic() - started < 1.5  # refused after resolution, not after a connect timeout


def test_error_texts_say_only_that_the_context_could_not_be_loaded(allowed, hostile):
    """A 404, a closed port and a non-JSON answer read the same: no status,
    no exception name, nothing a port scan could use."""
    targets = [
        hostile.status("/missing.jsonld", 404),
        hostile.status("/broken.jsonld", 500),
        hostile.document("/text.jsonld", b"<html>hello</html>"),
        hostile.document("/array.jsonld", [1, 2]),
        "http://127.0.0.1:9/closed.jsonld",
    ]
    for url in targets:
        got = allowed.get(ENTITIES, params={"type": "Sensor"}, headers=link(url))
        assert got.status_code == 503 and error_type(got) == "LdContextNotAvailable", got.text
        assert got.json()["detail"] == f"context could not be loaded: {url}"


def test_redirects_are_few_and_each_is_checked_again(client_factory, store_url, hostile):
    allow = f"{hostile.url}/open/"
    hostile.document("/open/ctx.jsonld", VICTIM)
    hostile.document("/secret.jsonld", VICTIM)
    one = hostile.redirect("/open/one", "/open/ctx.jsonld")
    out = hostile.redirect("/open/out", "/secret.jsonld")
    chain = hostile.redirect("/open/r1", "/open/r2")
    hostile.redirect("/open/r2", "/open/r3")
    hostile.redirect("/open/r3", "/open/r4")
    hostile.redirect("/open/r4", "/open/ctx.jsonld")
    with client_factory(store_url, ld_context_allow=allow) as client:
        assert client.get(ENTITIES, params={"type": "Sensor"}, headers=link(one)).status_code == 200
        refused = client.get(ENTITIES, params={"type": "Sensor"}, headers=link(out))
        assert refused.status_code == 503 and refused.json()["detail"] == f"context could not be loaded: {out}"
        assert hostile.hit("/secret.jsonld") == 0  # the redirect left the allowed prefix: not followed
        assert client.get(ENTITIES, params={"type": "Sensor"}, headers=link(chain)).status_code == 503
        assert hostile.hit("/open/r4") == 1 and hostile.hit("/open/ctx.jsonld") == 1  # the 4th redirect is not


def test_the_checked_address_is_the_one_connected_to_with_the_name_as_host(hostile):
    """Connect-by-IP: the server sees the URL's name in Host, not the address."""
    url = hostile.document("/ctx.jsonld", VICTIM).replace("127.0.0.1", "localhost")
    body = anyio.run(fetch, url, FetchPolicy(allow=(f"http://localhost:{hostile.port}/",)))
    assert json.loads(body) == VICTIM
    assert hostile.hosts == [f"localhost:{hostile.port}"]
    with pytest.raises(FetchFailed, match="non-public"):
        anyio.run(fetch, url, FetchPolicy())


# --- time and bytes ---------------------------------------------------------------------------


def test_a_trickling_context_hits_the_total_deadline(client_factory, store_url, hostile):
    url = hostile.slow("/slow.jsonld", interval=0.2)
    with client_factory(store_url, ld_context_allow=LOCAL, ngsild_context_timeout=1.0) as client:
        started = time.monotonic()
        got = client.get(ENTITIES, params={"type": "Sensor"}, headers=link(url))
        assert got.status_code == 503 and got.json()["detail"] == f"context could not be loaded: {url}"
        assert time.monotonic() - started < 2.5  # one deadline for the whole fetch, not one per read


def test_slow_contexts_do_not_stall_other_requests(hostile, tmp_path):
    """60 requests whose context trickles in, against the real server: they
    wait as coroutines, so /version, /health and a normal query answer at once."""
    url = hostile.slow("/slow.jsonld", interval=0.5)
    env = {"TSDB_LD_CONTEXT_ALLOW": LOCAL, "TSDB_NGSILD_CONTEXT_TIMEOUT": "6"}
    with ServerProcess(tmp_path / "tsdb.duckdb", extra_env=env) as server:
        statuses: list[int] = []

        def slow_query() -> None:
            got = httpx.get(server.url + ENTITIES, params={"type": "Sensor"}, headers=link(url), timeout=30)
            statuses.append(got.status_code)

        threads = [threading.Thread(target=slow_query) for _ in range(60)]
        for thread in threads:
            thread.start()
        time.sleep(1.0)
        with httpx.Client(base_url=server.url, timeout=10) as http:
            for path in ("/version", "/health", ENTITIES + "?type=Sensor"):
                started = time.monotonic()
                answer = http.get(path)
                assert answer.status_code == 200, answer.text
                assert time.monotonic() - started < 1.0, path
        for thread in threads:
            thread.join(30)
        assert statuses == [503] * 60


def test_a_gzip_bomb_is_cut_off_while_inflating(allowed, hostile):
    bomb = hostile.gzip_bomb("/bomb.jsonld", inflated=256 << 20)
    tracemalloc.start()
    try:
        with pytest.raises(FetchFailed, match="larger than"):
            anyio.run(fetch, bomb, FetchPolicy(allow=(LOCAL,), max_bytes=1 << 20))
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < 8 << 20, peak  # 256 MiB inflated would be; the cap keeps it near 1 MiB
    got = allowed.get(ENTITIES, params={"type": "Sensor"}, headers=link(bomb))
    assert got.status_code == 503 and got.json()["detail"] == f"context could not be loaded: {bomb}"
    # a small gzipped context is fine
    small = hostile.gzip_bomb("/small.jsonld", inflated=1000)  # 1000 zero bytes: not JSON
    assert allowed.get(ENTITIES, headers=link(small)).status_code == 503


# --- the cache: only valid documents, bounded, expiring, immutable ---------------------------


def _padded(n: int, valid: bool, size: int) -> dict:
    terms = {f"t{n}_{i}": f"https://example.org/{'x' * 200}/{n}/{i}" for i in range(size // 240)}
    if not valid:
        terms["broken"] = {"@id": 5}
    return {"@context": terms}


def test_only_valid_contexts_are_cached_and_the_cache_is_bounded(client_factory, store_url, hostile):
    with client_factory(store_url, ld_context_allow=LOCAL, ld_context_cache_bytes=2 << 20) as client:
        for n in range(12):
            url = hostile.document(f"/bad{n}.jsonld", _padded(n, False, 500_000))
            got = client.get(ENTITIES, params={"type": "Sensor"}, headers=link(url))
            assert got.status_code == 400 and error_type(got) == "BadRequestData", got.text
        assert contexts_of(client).cached_bytes == 0
        for n in range(12):
            url = hostile.document(f"/good{n}.jsonld", _padded(n, True, 500_000))
            got = client.get(ENTITIES, params={"type": "Sensor"}, headers=link(url))
            assert got.status_code == 200, got.text
        assert 0 < contexts_of(client).cached_bytes <= 2 << 20


def test_cached_contexts_expire(allowed, hostile, monkeypatch):
    from tsdb_service.faces.ngsild import context

    url = hostile.document("/ctx.jsonld", VICTIM)
    for _ in range(3):
        assert allowed.get(ENTITIES, params={"type": "Sensor"}, headers=link(url)).status_code == 200
    assert hostile.hit("/ctx.jsonld") == 1
    monkeypatch.setattr(context, "CACHE_SECONDS", 0.0)
    assert allowed.get(ENTITIES, params={"type": "Sensor"}, headers=link(url)).status_code == 200
    assert hostile.hit("/ctx.jsonld") == 2


def test_a_request_cannot_change_what_a_cached_context_means(allowed, hostile):
    """The attack: an inline context that @imports the victim's context and
    redefines a term. PyLD merges an @import into the imported document; it
    now only ever gets copies, so the victim's context keeps its meaning."""
    victim = hostile.document("/victim.jsonld", VICTIM)
    twin = hostile.document("/twin.jsonld", VICTIM)
    store_sensor(allowed)

    def victim_sees() -> list:
        got = allowed.get(ENTITIES, params={"type": "Sensor", "attrs": VICTIM_IRI}, headers={**H, **link(victim)})
        assert got.status_code == 200, got.text
        return got.json()

    attack = {"@import": victim, "temperature": "http://evil.example/t"}
    for _ in range(2):
        hit = ld_query(allowed, attack, headers={"NGSILD-Tenant": "attacker"})
        assert hit.status_code == 404 and error_type(hit) == "NonexistentTenant", hit.text
        hit = ld_query(allowed, [attack, victim])
        assert hit.status_code == 200, hit.text
    seen = victim_sees()
    assert [e["id"] for e in seen] == [SENSOR] and seen[0]["temperature"][0]["value"] == 21
    assert contexts_of(allowed).term_map(victim).expand("temperature") == VICTIM_IRI
    same = allowed.get(ENTITIES, params={"type": "Sensor", "attrs": VICTIM_IRI}, headers={**H, **link(twin)})
    assert same.status_code == 200 and [e["id"] for e in same.json()] == [SENSOR]


# --- inline and relative contexts, offline mode ------------------------------------------------


def test_large_inline_contexts_are_refused_and_what_is_kept_is_bounded(client_factory, store_url):
    with client_factory(store_url, ld_context_cache_bytes=1 << 20) as client:
        started = time.monotonic()
        huge = ld_query(client, _padded(0, True, 1_000_000)["@context"])
        assert huge.status_code == 400 and error_type(huge) == "BadRequestData", huge.text
        assert "TSDB_LD_INLINE_CONTEXT_MAX_BYTES" in huge.json()["detail"]
        assert time.monotonic() - started < 1.0
        for n in range(40):
            assert ld_query(client, _padded(n, True, 50_000)["@context"]).status_code == 200
        assert contexts_of(client).cached_bytes <= 1 << 20


@pytest.mark.parametrize(
    "context",
    ["x", ["x"], {"@import": "x"}, {"t": {"@id": "https://example.org/t", "@context": "x"}}, "file:///etc/passwd"],
)
def test_relative_and_non_http_contexts_are_400(client, context):
    got = ld_query(client, context)
    assert got.status_code == 400 and error_type(got) == "BadRequestData", got.text


def test_offline_mode_fetches_nothing(client_factory, store_url, hostile, tmp_path):
    url = hostile.document("/ctx.jsonld", VICTIM)
    local = tmp_path / "ctx.jsonld"
    local.write_text(json.dumps(VICTIM))
    configured = "https://contexts.example/victim.jsonld"
    settings = {"ld_context_allow": LOCAL, "ld_context_offline": True, "ngsild_contexts": f"{configured}={local}"}
    with client_factory(store_url, **settings) as client:
        store_sensor(client)
        got = client.get(ENTITIES, params={"type": "Sensor"}, headers=link(url))
        assert got.status_code == 503 and error_type(got) == "LdContextNotAvailable"
        assert hostile.hits == {}
        for ok in (CORE_CONTEXT_URL, configured):
            answer = client.get(ENTITIES, params={"type": "Sensor"}, headers={**H, **link(ok)})
            assert answer.status_code == 200 and [e["id"] for e in answer.json()] == [SENSOR], answer.text
