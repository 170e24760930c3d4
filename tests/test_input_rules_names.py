"""Accepted means addressable: one rule for ids, types and service paths.

Before: a service path with a space or a component over 256 characters, an
entity id or type over 1,024 characters, and a type with a comma or
surrounding spaces were stored with 200 but refused by every query and
delete; an id containing ``/`` (NGSI-LD ids are URIs) gave 404 on
``/v2/entities/{id}`` even as ``%2F``. Now ``tsdb_service.parse.names`` holds
one rule per kind, applied at ingest (400, notification kept) and by every
endpoint; whatever is stored is reached on every endpoint by its exact name,
``/`` as ``%2F`` in path segments, over real HTTP.
"""

from __future__ import annotations

import itertools
import threading
import time
from urllib.parse import quote

import httpx
import orjson
import pytest
import uvicorn

from tests.support.server import free_port

T0 = "2024-05-01T10:00:00Z"


def notification(entity_id: str, entity_type: str, attr: str = "x", value: float = 1.0) -> dict:
    return {
        "subscriptionId": "s",
        "data": [
            {
                "id": entity_id,
                "type": entity_type,
                attr: {"type": "Number", "value": value},
                "TimeInstant": {"type": "DateTime", "value": T0},
            }
        ],
    }


def seg(text: str) -> str:
    """One URL path segment, every reserved character percent-encoded."""
    return quote(text, safe="")


# --- refused at ingest, kept ----------------------------------------------------------------------
#
# One store per backend for the refusals and the query-side rules: each
# refusal is sent for a tenant of its own, so what it finds kept is its own.


@pytest.fixture(scope="module")
def rules(client_factory, store_url_factory):
    with client_factory(store_url_factory("rules")) as client:
        yield client


_TENANTS = itertools.count(1)


@pytest.fixture
def client(rules):
    """The module's store (this module's ``client``), read-only or on a tenant of the test's own."""
    return rules


REFUSED_IDS = ["x" * 1025, "a,b", " a", "a ", "a\u3000", "a\x00b", "a\x1fb", "a\x85", ".", ".."]
REFUSED_TYPES = ["x" * 1025, "T,U", " T", "T ", "T\t", "T\n", ".."]
REFUSED_PATHS = ["/a b", "/" + "x" * 257, "/ok/" + "y" * 300, "/a\tb", "/a#b", "/a//b", "//"]


@pytest.mark.parametrize("entity_id", REFUSED_IDS)
def test_unaddressable_id_is_refused_and_kept(client, entity_id):
    what = "data[0].id holds the NUL character" if "\x00" in entity_id else "entity id"  # no NUL anywhere
    _refused(client, notification(entity_id, "T"), {}, what)


@pytest.mark.parametrize("entity_type", REFUSED_TYPES)
def test_unaddressable_type_is_refused_and_kept(client, entity_type):
    _refused(client, notification("E1", entity_type), {}, "entity type")


@pytest.mark.parametrize("path", REFUSED_PATHS)
def test_unaddressable_service_path_is_refused_and_kept(client, path):
    _refused(client, notification("E1", "T"), {"Fiware-ServicePath": path}, "service path")


def test_ngsi_ld_type_list_is_checked(client):
    body = {"id": "urn:n", "type": "Notification", "data": [{"id": "urn:E", "type": ["A,B", "C"]}]}
    _refused(client, body, {}, "entity type")


def test_values_layout_refuses_an_unaddressable_entity(client):
    response = client.put("/v2/notify/subscriptions/s1", json={"attrs": ["x"], "entityId": "a,b"})
    assert response.status_code == 400, response.text


def _refused(client, body: dict, headers: dict, what: str) -> None:
    tenant = f"rules{next(_TENANTS)}"
    headers = {"Fiware-Service": tenant, **headers}
    response = client.post(
        "/v2/notify", content=orjson.dumps(body), headers={"Content-Type": "application/json", **headers}
    )
    assert response.status_code == 400, response.text
    assert what in response.json()["description"]
    [kept] = client.get("/v2/notify/rejected", headers={"Fiware-Service": tenant}).json()
    assert orjson.loads(kept["body"]) == body
    assert client.get("/v2/entities", headers={"Fiware-Service": tenant}).json() == []


# --- the query side applies the same rule ---------------------------------------------------------


@pytest.mark.parametrize("url", ["/v2/entities/{}", "/v2/entities/{}/attrs/x", "/v2/types/{}", "/v2/types/{}/attrs/x"])
@pytest.mark.parametrize("name", ["x" * 1025, "a,b", " a", "a\x00"])
def test_queries_refuse_what_the_ingest_refuses(client, url, name):
    response = client.get(url.format(seg(name)))
    assert response.status_code == 400, response.text


@pytest.mark.parametrize("params", [{"id": "x" * 1025}, {"type": "x" * 1025}, {"id": "a\x01"}])
def test_list_parameters_follow_the_rule(client, params):
    assert client.get("/v2/entities", params=params).status_code == 400
    assert client.get("/grafana/infinity/entities", params=params).status_code == 400


def test_op_query_follows_the_rule(client):
    response = client.post("/v2/op/query", json={"entities": [{"id": "x" * 1025}]})
    assert response.status_code == 400, response.text
    response = client.post("/v2/op/query", json={"entities": [{"id": "E", "type": " T"}]})
    assert response.status_code == 400, response.text


@pytest.mark.parametrize("path", REFUSED_PATHS[:-2])
def test_query_service_paths_follow_the_rule(client, path):
    response = client.get("/v2/entities", headers={"Fiware-ServicePath": path})
    assert response.status_code == 400, response.text


# --- everything stored is reached by its name, over real HTTP ---------------------------------------------

IDS = [
    "urn:ngsi-ld:Robot:a/b",
    "https://example.org/e/1?q=1&r=2#frag",
    "a%2Fb",
    "50%",
    "%",
    "a b",
    "value",
    "attrs",
    "ü/ü",
    "a;b=c(d)",
    "x" * 1024,
    "/leading",
    "trailing/",
    "a//b",
    "E1",
]
TYPES = ["https://uri.fiware.org/ns/data-models#Robot", "a/b", "T%2F", "t" * 1024, "Type With Spaces"]
ATTRS = ["https://example.org/ns/speed", "a/b", "value", "p%2Fq", "ex:x"]
PATHS = ["/" + "c" * 256, "/a/b/c", "/ünï/códe"]


class _Server(uvicorn.Server):
    def install_signal_handlers(self) -> None:  # a test thread must not take pytest's signals
        pass


@pytest.fixture(scope="module")
def served(app_factory, store_url_factory):
    """The app behind real uvicorn (the path decoding under test is the
    server's), holding one entity per id, type and attribute name."""
    server = _Server(
        uvicorn.Config(
            app_factory(store_url_factory("names")),
            host="127.0.0.1",
            port=free_port(),
            log_level="warning",
            lifespan="on",
        )
    )
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    while not server.started:
        assert thread.is_alive()
        time.sleep(0.02)
    url = f"http://127.0.0.1:{server.config.port}"
    with httpx.Client(base_url=url, timeout=30.0, headers={"Fiware-Service": "rules"}) as http:
        for i, entity_id in enumerate(IDS):
            attr, entity_type = ATTRS[i % len(ATTRS)], TYPES[i % len(TYPES)]
            path = PATHS[i % len(PATHS)]
            response = http.post(
                "/v2/notify",
                json=notification(entity_id, entity_type, attr, i),
                headers={"Fiware-ServicePath": path.encode()},
            )
            assert response.status_code == 200, response.text
        yield http
    server.should_exit = True
    thread.join(timeout=30)


def _case(i: int) -> tuple[str, str, str, str]:
    return IDS[i], TYPES[i % len(TYPES)], ATTRS[i % len(ATTRS)], PATHS[i % len(PATHS)]


@pytest.mark.parametrize("i", range(len(IDS)))
def test_every_history_endpoint_reaches_it(served, i):
    entity_id, entity_type, attr, path = _case(i)
    one = served.get(f"/v2/entities/{seg(entity_id)}")
    assert one.status_code == 200, one.text
    assert one.json()["id"] == entity_id
    assert {a["attrName"]: a["values"] for a in one.json()["attributes"]}[attr] == [i]
    values = served.get(f"/v2/entities/{seg(entity_id)}/value").json()["attributes"]
    assert {a["attrName"]: a["values"] for a in values}[attr] == [i]
    for url in (
        f"/v2/entities/{seg(entity_id)}/attrs/{seg(attr)}",
        f"/v2/entities/{seg(entity_id)}/attrs/{seg(attr)}/value",
    ):
        response = served.get(url)
        assert response.status_code == 200, (url, response.text)
        assert response.json()["values"] == [i]
    typed = served.get(f"/v2/types/{seg(entity_type)}", params={"id": entity_id}).json()
    assert typed["type"] == entity_type and [e["id"] for e in typed["entities"]] == [entity_id]
    response = served.get(f"/v2/types/{seg(entity_type)}/attrs/{seg(attr)}", params={"id": entity_id})
    assert response.status_code == 200, response.text
    assert response.status_code == 200 and response.json()["entities"][0]["values"] == [i]
    if attr != "value":  # /v2/attrs/value is QuantumLeap's values-only form of /v2/attrs
        response = served.get(f"/v2/attrs/{seg(attr)}", params={"id": entity_id})
        assert response.status_code == 200, response.text
        assert response.json()["attrName"] == attr
    response = served.get("/v2/attrs", params={"id": entity_id, "attrs": attr})
    assert [a["attrName"] for a in response.json()["attrs"]] == [attr]
    listed = served.get("/v2/entities", params={"id": entity_id, "type": entity_type}).json()
    assert [e["id"] for e in listed] == [entity_id]
    # ...and within its service path, named in the query header.
    scoped = served.get(f"/v2/entities/{seg(entity_id)}", headers={"Fiware-ServicePath": path.encode()})
    assert scoped.status_code == 200, scoped.text


@pytest.mark.parametrize("i", range(len(IDS)))
def test_op_query_and_grafana_reach_it(served, i):
    entity_id, entity_type, attr, _ = _case(i)
    [found] = served.post("/v2/op/query", json={"entities": [{"id": entity_id, "type": entity_type}]}).json()
    assert found["id"] == entity_id and found[attr]["value"] == i
    rows = served.get(
        "/grafana/infinity/latest", params={"id": entity_id, "type": entity_type, "attrs": f"v={attr}"}
    ).json()
    assert [(r["entity"], r["v"]) for r in rows] == [(entity_id, i)]


def test_an_encoded_slash_never_reaches_another_route(served):
    # "/v2/entities/urn%2Fvalue" is the entity "urn/value", not /value of "urn".
    served.post("/v2/notify", json=notification("urn", "T"))
    served.post("/v2/notify", json=notification("urn/value", "T", value=7))
    assert served.get("/v2/entities/urn%2Fvalue").json()["id"] == "urn/value"
    assert served.get("/v2/entities/urn%2fvalue").json()["id"] == "urn/value"
    assert "id" not in served.get("/v2/entities/urn/value").json()  # the values-only form of "urn"
    nope = served.get("/v2/entities/urn%2Fnope")
    assert nope.status_code == 404 or not nope.json()


def test_delete_by_encoded_names(served):
    for entity_id in ("del/a", "del%2Fb"):
        assert served.post("/v2/notify", json=notification(entity_id, "Del/Type")).status_code == 200

    def stored() -> list[str]:
        return [e["id"] for e in served.get("/v2/entities", params={"type": "Del/Type"}).json()]

    assert stored() == ["del%2Fb", "del/a"]
    response = served.delete(f"/v2/entities/{seg('del/a')}")
    assert response.status_code == 204, response.text
    assert stored() == ["del%2Fb"]
    assert served.delete(f"/v2/types/{seg('Del/Type')}").status_code == 204
    assert stored() == []


def test_other_routes_keep_their_decoding(served):
    # Only the history and delete routes see raw segments.
    assert served.get("/dashboards/lawn%6Dower").status_code == 200
