"""Temporal pagination, both bindings, chosen by what the request uses.

* ETSI TS 104 176 clause 6.4.7.3 (``firstN``, ``offsetN``, or our links):
  always 200; per attribute the oldest (``firstN``) or newest (``lastN``)
  N past ``offsetN``, each attribute on its own; ``Link`` ``intervalafter``
  (later instances) and ``intervalbefore`` (earlier ones); ``firstN`` with
  ``lastN`` is a 400.
* ETSI GS CIM 009 V1.9.1 clause 6.3.10 (only ``lastN`` or no instance
  parameter): 206 with ``Content-Range`` past the instance cap
  (``test_ngsild_render`` walks it); a ``lastN`` answer that fits is 200
  and links the earlier instances for clients of the newer binding.

The links are followed to the end while instances keep arriving: none of
the instances there at the first page is skipped or repeated.
"""

from __future__ import annotations

import threading
import time
from datetime import UTC, datetime, timedelta
from urllib.parse import parse_qs, urlsplit

import httpx
import pytest

from tests.ngsild_fixtures import ENTITIES, H, error_type, get
from tests.support.serving import serving

E1 = "urn:ngsi-ld:Robot:p1"
E2 = "urn:ngsi-ld:Robot:p2"
T0 = datetime(2024, 5, 1, 10, 0, tzinfo=UTC)


def at(minutes: float) -> str:
    return (T0 + timedelta(minutes=minutes)).isoformat().replace("+00:00", "Z")


def instances(values: list[tuple[float, float]]) -> list[dict]:
    return [{"type": "Property", "value": v, "observedAt": at(m)} for m, v in values]


def robot(eid: str, speeds: int = 7, fuels: int = 4) -> dict:
    """``speed`` every minute, ``fuel`` every other minute and a half past:
    the two attributes' instances never share an instant."""
    return {
        "id": eid,
        "type": "Robot",
        "speed": instances([(m, m) for m in range(speeds)]),
        "fuel": instances([(2 * m + 0.5, 100 - m) for m in range(fuels)]),
    }


def create(client, body: dict) -> None:
    response = client.post(ENTITIES, json=body, headers=H)
    assert response.status_code == 201, response.text


@pytest.fixture
def robots(client):
    create(client, robot(E1))
    create(client, robot(E2, speeds=2, fuels=1))
    return client


def links(response) -> dict[str, str]:
    """rel → target of the response's ``Link`` values (the @context link left out)."""
    out = {}
    for part in response.headers.get("Link", "").split(", <"):
        target, _, rest = part.lstrip("<").partition(">;")
        rel = rest.split('rel="', 1)[-1].split('"', 1)[0]
        if rel.startswith("interval"):
            assert 'type="application/json"' in rest, part
            out[rel] = target
    return out


def query_of(target: str) -> dict[str, str]:
    return {k: v[0] for k, v in parse_qs(urlsplit(target).query).items()}


def values(entity: dict, attr: str) -> list:
    return [i["value"] for i in entity.get(attr, [])]


def test_first_n_pages_each_attribute_oldest_first_on_its_own(robots):
    """TS 104 176 clause 6.4.7.3: firstN is per attribute, oldest first;
    unsynchronized attributes page independently (no common cut)."""
    page = get(robots, path=f"{ENTITIES}/{E1}", params={"firstN": "3"})
    assert values(page.json(), "speed") == [0, 1, 2] and values(page.json(), "fuel") == [100, 99, 98]
    assert "Content-Range" not in page.headers
    rels = links(page)
    assert set(rels) == {"intervalafter"}
    after = query_of(rels["intervalafter"])
    assert after["offsetN"] == "3" and after["firstN"] == "3" and after["storedThrough"].isdigit()
    second = robots.get(rels["intervalafter"], headers=H)
    assert second.status_code == 200
    assert values(second.json(), "speed") == [3, 4, 5] and values(second.json(), "fuel") == [97]
    assert query_of(links(second)["intervalbefore"])["offsetN"] == "0"  # the page before: the relation swaps
    third = robots.get(links(second)["intervalafter"], headers=H).json()
    assert values(third, "speed") == [6] and "fuel" not in third


def test_last_n_pages_newest_first(robots):
    """clause 6.4.7.3: lastN, newest first; the next page holds earlier
    instances, so it is intervalbefore."""
    page = get(robots, path=f"{ENTITIES}/{E1}", params={"lastN": "3"})
    assert values(page.json(), "speed") == [4, 5, 6] and values(page.json(), "fuel") == [99, 98, 97]
    before = links(page)["intervalbefore"]
    assert query_of(before)["offsetN"] == "3" and "intervalafter" not in links(page)
    older = robots.get(before, headers=H)
    assert values(older.json(), "speed") == [1, 2, 3] and values(older.json(), "fuel") == [100]
    assert query_of(links(older)["intervalafter"])["offsetN"] == "0"
    last = robots.get(links(older)["intervalbefore"], headers=H).json()
    assert values(last, "speed") == [0] and "fuel" not in last


def test_offset_n_selects_a_page(robots):
    """clause 6.4.7.3: offsetN skips N instances per attribute in firstN's
    or lastN's order; without either, oldest first."""
    page = get(robots, path=f"{ENTITIES}/{E1}", params={"firstN": "2", "offsetN": "2"}).json()
    assert values(page, "speed") == [2, 3] and values(page, "fuel") == [98, 97]
    newest = get(robots, path=f"{ENTITIES}/{E1}", params={"lastN": "2", "offsetN": "1"}).json()
    assert values(newest, "speed") == [4, 5] and values(newest, "fuel") == [99, 98]
    alone = get(robots, path=f"{ENTITIES}/{E1}", params={"offsetN": "5"}).json()
    assert values(alone, "speed") == [5, 6] and "fuel" not in alone


def test_first_n_with_last_n_is_a_bad_request(robots):
    """clause 6.4.7.3: the two directions exclude each other."""
    response = get(robots, path=f"{ENTITIES}/{E1}", params={"firstN": "2", "lastN": "2"}, status=400)
    assert error_type(response) == "BadRequestData"


def test_a_query_pages_every_entity_and_attribute(robots):
    """The temporal query: each entity's attributes page on their own; the
    link moves the instances, not the entities."""
    page = get(robots, params={"type": "Robot", "firstN": "2"})
    got = {e["id"]: (values(e, "speed"), values(e, "fuel")) for e in page.json()}
    assert got == {E1: ([0, 1], [100, 99]), E2: ([0, 1], [100])}
    rest = robots.get(links(page)["intervalafter"], headers=H).json()
    assert {e["id"]: (values(e, "speed"), values(e, "fuel")) for e in rest} == {E1: ([2, 3], [98, 97]), E2: ([], [])}


def test_always_200_past_the_cap(client_factory, store_url):
    """clause 6.4.7.3: no 206 in the newer binding. When N per attribute
    passes the instance cap, every attribute gets the K that fit and the
    link goes on from offsetN + K. A request in V1.9.1's terms still gets
    206 and Content-Range (clause 6.3.10)."""
    with client_factory(store_url, ngsild_max_instances=4) as client:
        create(client, robot(E1))
        page = get(client, path=f"{ENTITIES}/{E1}", params={"firstN": "3"})
        assert values(page.json(), "speed") == [0, 1] and values(page.json(), "fuel") == [100, 99]
        assert query_of(links(page)["intervalafter"])["offsetN"] == "2"
        old = get(client, path=f"{ENTITIES}/{E1}", status=206)
        assert old.headers["Content-Range"].startswith("date-time ")
    with client_factory(store_url, ngsild_max_instances=1) as client:
        too_many = get(client, path=f"{ENTITIES}/{E1}", params={"firstN": "1"}, status=403)
        assert error_type(too_many) == "TooManyResults"  # not even one instance of each attribute fits


def test_a_last_n_answer_that_fits_links_the_earlier_instances(robots):
    """A V1.9.1 request (lastN alone) answered whole is 200 without
    Content-Range; it names the earlier page for the newer binding's
    clients, and none when there is nothing earlier."""
    page = get(robots, path=f"{ENTITIES}/{E1}", params={"lastN": "5"})
    assert "Content-Range" not in page.headers and "intervalbefore" in links(page)
    whole = get(robots, path=f"{ENTITIES}/{E2}", params={"lastN": "5"})
    assert "Link" not in whole.headers or not links(whole)


def test_a_query_body_pages_through_temporal_q(robots):
    """A Query's temporalQ carries firstN (TS 104 175 clause 5.2.21's
    TemporalQuery); the link names the query string the same body is sent
    to again."""
    body = {"type": "Query", "entities": [{"type": "Robot", "id": E1}], "temporalQ": {"firstN": 4}}
    url = "/ngsi-ld/v1/temporal/entityOperations/query"
    first = robots.post(url, json=body, headers=H)
    assert first.status_code == 200 and values(first.json()[0], "speed") == [0, 1, 2, 3]
    rest = robots.post(links(first)["intervalafter"], json=body, headers=H)
    assert values(rest.json()[0], "speed") == [4, 5, 6]


def _walk(base: str, params: dict, rel: str) -> list[list[str]]:
    """Follow ``rel`` from the first page to the end; each page's instanceIds."""
    pages = []
    with httpx.Client(base_url=base, headers=H, timeout=30) as http:
        response = http.get(f"{ENTITIES}/{E1}", params=params)
        while True:
            assert response.status_code == 200, response.text
            body = response.json()
            pages.append([i["instanceId"] for attr in ("speed", "fuel") for i in body.get(attr, [])])
            target = links(response).get(rel)
            if target is None:
                return pages
            response = http.get(target)


@pytest.mark.parametrize(("params", "rel"), [({"firstN": "3"}, "intervalafter"), ({"lastN": "3"}, "intervalbefore")])
def test_walking_the_links_while_instances_arrive_skips_and_repeats_nothing(app_factory, store_url, params, rel):
    """clause 6.4.7.3's links, anchored on the instances stored when the
    walk began (storedThrough): new instances, newer ones and late ones
    inside the walked range, do not move the pages."""
    with serving(app_factory(store_url)) as base:
        with httpx.Client(base_url=base, headers=H, timeout=30) as http:
            assert http.post(ENTITIES, json=robot(E1, speeds=20, fuels=12)).status_code == 201
            before = http.get(f"{ENTITIES}/{E1}").json()
        initial = {i["instanceId"] for attr in ("speed", "fuel") for i in before[attr]}
        stop = threading.Event()

        def keep_writing() -> None:
            with httpx.Client(base_url=base, headers=H, timeout=30) as http:
                for n in range(1000):
                    if stop.is_set():
                        return
                    late, new = at(n % 30 + 0.25), at(100 + n)  # one inside the walked range, one after it
                    body = {"speed": instances([(100 + n, -1.0)]), "fuel": [{"type": "Property", "value": -1,
                                                                           "observedAt": late}]}  # fmt: skip
                    assert http.post(f"{ENTITIES}/{E1}/attrs", json=body).status_code == 204, new
                    time.sleep(0.002)

        writer = threading.Thread(target=keep_writing, daemon=True)
        writer.start()
        try:
            time.sleep(0.05)  # the first page sees some of the new instances already
            pages = _walk(base, params, rel)
        finally:
            stop.set()
            writer.join(timeout=30)
    seen = [iid for page in pages for iid in page]
    assert len(seen) == len(set(seen)), "an instance came twice"
    assert initial <= set(seen), f"skipped: {sorted(initial - set(seen))[:5]}"
    assert len(pages) >= 7
