"""``tsdb-service register``: this service as an NGSI-LD broker's temporal
context source (ETSI GS CIM 009 clause 5.2.9 CSourceRegistration, clause
4.3.6 distributed operations), registered once.

The broker is a stand-in over real HTTP (``tests.support.ld_registry``):
it keeps registrations per tenant, lists them paged, and forwards its
temporal reads to the registrations that list them, as a broker with
distributed operations does. The last test runs tsdb-service itself (on
both backends) and asks the broker, not us, for the history.
"""

from __future__ import annotations

import httpx
import pytest

from tests.ngsild_fixtures import B9211, TENANT, load_vehicles
from tests.support.ld_registry import LdRegistry
from tests.support.serving import serving
from tsdb_service.broker.registrations import Registration, equivalent
from tsdb_service.cli.main import main

ENDPOINT = "http://tsdb-service:8668"
LINK = '<https://example.org/ctx.jsonld>; rel="http://www.w3.org/ns/json-ld#context"; type="application/ld+json"'


@pytest.fixture
def registry():
    stand_in = LdRegistry()
    with serving(stand_in.app) as url:
        stand_in.url = url
        yield stand_in


def _register(registry, *extra: str, endpoint: str = ENDPOINT) -> int:
    return main(["register", "--broker", registry.url, "--type", "Vehicle", "--endpoint", endpoint, *extra])


def test_the_registration_is_an_auxiliary_source_of_the_temporal_reads(registry, capsys):
    """Clause 5.2.9: an auxiliary registration (mode, clause 4.3.6) of the
    two temporal reads, for the types given, in the tenant given, the type
    names read with the @context given (Link)."""
    assert (
        _register(registry, "--tenant", "fleet", "--type", "Bus,Car", "--context", "https://example.org/ctx.jsonld")
        == 0
    )
    [(tenant, body)] = registry.received
    assert tenant == "fleet"
    assert body["type"] == "ContextSourceRegistration" and body["mode"] == "auxiliary"
    assert body["operations"] == ["retrieveTemporal", "queryTemporal"]
    assert body["endpoint"] == ENDPOINT
    assert body["information"] == [{"entities": [{"type": "Vehicle"}, {"type": "Bus"}, {"type": "Car"}]}]
    out = capsys.readouterr().out
    assert f"endpoint: {ENDPOINT}" in out and "201 Created" in out and "tenant 'fleet'" in out
    assert Registration(ENDPOINT, ("Vehicle",), context="https://example.org/ctx.jsonld").headers()["Link"] == LINK


def test_running_twice_registers_once(registry, capsys):
    assert _register(registry) == 0
    assert _register(registry) == 0
    out = capsys.readouterr().out.splitlines()[-1]
    [registration] = registry.registrations[""]
    assert "already registered" in out and registration["id"] in out and "--force" in out, out


def test_force_registers_another(registry):
    assert _register(registry) == 0
    assert _register(registry, "--force") == 0
    assert len(registry.registrations[""]) == 2


def test_an_equivalent_registration_past_the_first_page_is_found(registry):
    for endpoint in ("http://a:8668", "http://b:8668", ENDPOINT):
        assert _register(registry, endpoint=endpoint) == 0
    assert _register(registry) == 0  # the stand-in lists two a page: the third is on page two
    assert len(registry.registrations[""]) == 3


@pytest.mark.parametrize(
    "change",
    [
        {"endpoint": "http://elsewhere:8668"},
        {"mode": "inclusive"},
        {"operations": ["retrieveTemporal"]},
        {"information": [{"entities": [{"type": "Vehicle"}, {"type": "Bus"}]}]},
    ],
)
def test_what_is_not_equivalent_does_not_count(change):
    wanted = Registration(ENDPOINT, ("Vehicle",))
    assert equivalent({**wanted.document(), "id": "x"}, wanted)
    assert equivalent({**wanted.document(), "endpoint": ENDPOINT + "/"}, wanted)
    assert not equivalent({**wanted.document(), **change}, wanted)


def test_a_broker_that_cannot_list_gets_nothing(registry, capsys):
    registry.listing_fails = True
    assert _register(registry) == 1
    out = capsys.readouterr().out
    assert "500" in out and "nothing registered" in out and "--force" in out
    assert registry.received == []


def test_a_broker_that_refuses_says_why(registry, capsys):
    assert main(["register", "--broker", registry.url, "--type", "Vehicle", "--endpoint", "not-a-url"]) == 1
    assert "400" in capsys.readouterr().out


def test_an_unreachable_broker(capsys):
    from tests.support.server import free_port

    assert main(["register", "--broker", f"http://127.0.0.1:{free_port()}", "--type", "V", "--endpoint", ENDPOINT]) == 1
    out = capsys.readouterr().out
    assert "could not reach" in out and "--force" not in out


def test_types_are_needed(registry, capsys):
    assert main(["register", "--broker", registry.url, "--type", " , ", "--endpoint", ENDPOINT]) == 2
    assert "--type" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["register", "--broker", registry.url])


def test_the_default_endpoint_is_this_machine_and_is_printed(registry, capsys):
    assert main(["register", "--broker", registry.url, "--type", "Vehicle"]) == 0
    out = capsys.readouterr().out
    endpoint = registry.received[0][1]["endpoint"]
    assert endpoint.startswith("http://") and endpoint.endswith(":8668") and f"endpoint: {endpoint}" in out


def test_the_brokers_temporal_queries_are_served_from_our_history(registry, app_factory, store_url):
    """A client asks the broker for the temporal evolution; the broker
    forwards it to us, as registered, and answers with our history."""
    with serving(app_factory(store_url)) as service:
        with httpx.Client(base_url=service) as ours:
            load_vehicles(ours)
        assert _register(registry, "--tenant", TENANT, endpoint=service) == 0
        headers = {"NGSILD-Tenant": TENANT}
        params = {"type": "Vehicle", "attrs": "speed", "lastN": "2"}
        answer = httpx.get(f"{registry.url}/ngsi-ld/v1/temporal/entities", params=params, headers=headers, timeout=10)
        assert answer.status_code == 200, answer.text
        got = {e["id"]: [i["value"] for i in e["speed"]] for e in answer.json()}
        assert got[B9211] == [80, 100]
        one = httpx.get(f"{registry.url}/ngsi-ld/v1/temporal/entities/{B9211}", params=params, headers=headers)
        assert [i["value"] for i in one.json()["speed"]] == [80, 100]
