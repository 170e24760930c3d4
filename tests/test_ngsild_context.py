"""JSON-LD @contexts: the shipped core context, user contexts by Link
header (fetched from a real local HTTP server and cached), configured local
files, ld+json bodies, compaction of answers and the context errors."""

from __future__ import annotations

import json
import threading
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

import pytest

from tests.ngsild_fixtures import B9211, ENTITIES, H, error_type, get, ld_notify
from tsdb_service.core.errors import BadRequestData, LdContextNotAvailable
from tsdb_service.faces.ngsild.context import (
    CORE_CONTEXT_URL,
    DEFAULT_VOCAB,
    ContextStore,
    core_context,
    link_context,
    parse_local_contexts,
)
from tsdb_service.http.outbound import FetchPolicy

LOCAL = "http://127.0.0.1:"  # the test servers' URLs, allowed as TSDB_LD_CONTEXT_ALLOW allows them


def local_store(**kwargs) -> ContextStore:
    """A context store that may fetch from this machine's test servers."""
    return ContextStore(policy=FetchPolicy(allow=(LOCAL,), **kwargs))


@pytest.fixture
def client(client_factory, store_url):
    with client_factory(store_url, ld_context_allow=LOCAL) as c:
        yield c


USER_CONTEXT = {
    "@context": {"speed": "https://example.org/vehicle#speed", "Vehicle": "https://example.org/vehicle#Vehicle"}
}


class _Server:
    def __init__(self, documents: dict[str, object]):
        self.hits: dict[str, int] = {}
        server = self

        class Handler(BaseHTTPRequestHandler):
            def do_GET(self):
                server.hits[self.path] = server.hits.get(self.path, 0) + 1
                doc = documents.get(self.path)
                if doc is None:
                    self.send_response(404)
                    self.end_headers()
                    return
                payload = json.dumps(doc).encode()
                self.send_response(200)
                self.send_header("Content-Type", "application/ld+json")
                self.send_header("Content-Length", str(len(payload)))
                self.end_headers()
                self.wfile.write(payload)

            def log_message(self, *args):
                pass

        self.httpd = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.url = f"http://127.0.0.1:{self.httpd.server_address[1]}"
        self.thread = threading.Thread(target=self.httpd.serve_forever, daemon=True)
        self.thread.start()

    def close(self):
        self.httpd.shutdown()
        self.httpd.server_close()


@pytest.fixture
def context_server():
    server = _Server({"/vehicle.jsonld": USER_CONTEXT})
    yield server
    server.close()


def link(url: str) -> dict:
    return {"Link": f'<{url}>; rel="http://www.w3.org/ns/json-ld#context"; type="application/ld+json"'}


def test_core_context_ships_with_the_package():
    ctx = core_context()["@context"]
    assert ctx["@vocab"] == DEFAULT_VOCAB and ctx["observedAt"]["@id"] == "ngsi-ld:observedAt"
    terms = ContextStore().term_map(None)
    assert terms.expand("speed") == DEFAULT_VOCAB + "speed"
    assert terms.expand("location") == "https://uri.etsi.org/ngsi-ld/location"
    assert terms.compact(DEFAULT_VOCAB + "speed") == "speed"
    assert terms.expand("https://example.org/x") == "https://example.org/x"


def test_user_context_fetched_once_and_cached(context_server):
    store = local_store()
    url = context_server.url + "/vehicle.jsonld"
    terms = store.term_map(url)
    assert terms.expand_all(["speed", "Vehicle", "other"]) == [
        "https://example.org/vehicle#speed",
        "https://example.org/vehicle#Vehicle",
        DEFAULT_VOCAB + "other",
    ]
    assert terms.compact("https://example.org/vehicle#speed") == "speed"
    assert store.term_map(url) is terms
    assert local_store().term_map(url).expand("speed") and context_server.hits["/vehicle.jsonld"] >= 1
    before = context_server.hits["/vehicle.jsonld"]
    store.term_map([url]).expand("Vehicle")
    assert context_server.hits["/vehicle.jsonld"] == before  # the document is cached per store


def test_local_context_files(tmp_path):
    path = tmp_path / "ctx.jsonld"
    path.write_text(json.dumps(USER_CONTEXT))
    store = ContextStore(parse_local_contexts(f"https://contexts.example/vehicle.jsonld={path}"))
    assert (
        store.term_map("https://contexts.example/vehicle.jsonld").expand("speed") == "https://example.org/vehicle#speed"
    )
    with pytest.raises(ValueError):
        parse_local_contexts("no-equals-sign")


def test_unreachable_and_broken_contexts(context_server):
    store = local_store(deadline=0.5)
    with pytest.raises(LdContextNotAvailable):
        store.term_map(context_server.url + "/missing.jsonld")
    with pytest.raises(BadRequestData):
        store.term_map({"speed": {"@id": 5}})


def test_link_header_parsing():
    assert link_context(None) is None
    assert (
        link_context('<https://x.org/c.jsonld>; rel="http://www.w3.org/ns/json-ld#context"') == "https://x.org/c.jsonld"
    )
    assert link_context('<https://x.org/a>; rel="next"') is None
    with pytest.raises(BadRequestData):
        link_context(
            '<https://x.org/a>; rel="http://www.w3.org/ns/json-ld#context", '
            '<https://x.org/b>; rel="http://www.w3.org/ns/json-ld#context"'
        )
    with pytest.raises(BadRequestData):
        link_context('<file:///etc/passwd>; rel="http://www.w3.org/ns/json-ld#context"')


def test_query_with_a_user_context_expands_and_compacts(client, context_server):
    url = context_server.url + "/vehicle.jsonld"
    ld_notify(
        client,
        [
            {
                "id": B9211,
                "type": "Vehicle",
                "speed": {"type": "Property", "value": 9, "observedAt": "2018-08-01T12:00:00Z"},
                "https://example.org/vehicle#odometer": {
                    "type": "Property",
                    "value": 1,
                    "observedAt": "2018-08-01T12:00:00Z",
                },
            }
        ],
    )
    got = get(client, {"type": "Vehicle", "attrs": "speed"}, headers=link(url))
    assert got.json()[0]["speed"][0]["value"] == 9
    assert got.headers["Link"].startswith(f"<{url}>")
    full = get(
        client,
        {"type": "https://example.org/vehicle#Vehicle", "attrs": "https://example.org/vehicle#speed"},
        headers=link(url),
    )
    assert full.json()[0]["type"] == "Vehicle" and "speed" in full.json()[0]
    # without the user context the stored short names are core-context terms
    core = get(client, {"type": "Vehicle", "attrs": "https://example.org/vehicle#speed"})
    assert core.json() == []
    odometer = get(client, {"type": "Vehicle", "attrs": "https://example.org/vehicle#odometer"}).json()[0]
    assert "https://example.org/vehicle#odometer" in odometer


def test_accept_ld_json_puts_the_context_in_the_body(client, context_server):
    url = context_server.url + "/vehicle.jsonld"
    ld_notify(
        client,
        [
            {
                "id": B9211,
                "type": "Vehicle",
                "speed": {"type": "Property", "value": 9, "observedAt": "2018-08-01T12:00:00Z"},
            }
        ],
    )
    ld = get(client, {"type": "Vehicle"}, headers={**link(url), "Accept": "application/ld+json"})
    assert ld.headers["Content-Type"].startswith("application/ld+json")
    assert ld.json()[0]["@context"] == [url, CORE_CONTEXT_URL]
    assert "json-ld#context" not in ld.headers.get("Link", "")
    one = get(client, path=f"{ENTITIES}/{B9211}", headers={"Accept": "application/ld+json"})
    assert one.json()["@context"] == CORE_CONTEXT_URL
    plain = get(client, {"type": "Vehicle"}, headers={"Accept": "application/json"})
    assert "@context" not in plain.json()[0] and CORE_CONTEXT_URL in plain.headers["Link"]


def test_post_query_with_ld_json_body_context(client, context_server):
    url = context_server.url + "/vehicle.jsonld"
    ld_notify(
        client,
        [
            {
                "id": B9211,
                "type": "Vehicle",
                "speed": {"type": "Property", "value": 9, "observedAt": "2018-08-01T12:00:00Z"},
            }
        ],
    )
    body = {"type": "Query", "entities": [{"type": "Vehicle"}], "attrs": ["speed"], "@context": url}
    path = "/ngsi-ld/v1/temporal/entityOperations/query"
    ok = client.post(path, content=json.dumps(body), headers={**H, "Content-Type": "application/ld+json"})
    assert ok.status_code == 200, ok.text
    assert ok.json()[0]["speed"][0]["value"] == 9
    both = client.post(
        path, content=json.dumps(body), headers={**H, **link(url), "Content-Type": "application/ld+json"}
    )
    assert both.status_code == 400 and error_type(both) == "BadRequestData"
    no_ctx = client.post(path, json=body, headers=H)
    assert no_ctx.status_code == 400


def test_unreachable_context_is_503(client):
    got = get(client, {"type": "Vehicle"}, headers=link("http://127.0.0.1:9/none.jsonld"), status=503)
    assert error_type(got) == "LdContextNotAvailable"
