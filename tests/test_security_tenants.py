"""Issue 27, the edges of tenant boundaries with authentication on: the
guard and the routes authorise the tenant the route parses (``%73ervice``
is ``service``), answers that span tenants (``allTenants``, ``/ui/tenants``,
``/metrics``) are only for callers that may see every tenant, changing
history needs admin whatever the verb, and an unknown tenant reads like an
empty one. On both backends, with real stored data."""

from __future__ import annotations

import pytest
from starlette.requests import Request

from tsdb_service.core.errors import Forbidden
from tsdb_service.http.tenancy import PRINCIPAL, grafana_scope, tenant_of
from tsdb_service.security import Principal

ADMIN = "admin-key-0123456789abcdef"
ADMIN_A = "admin-a-key-0123456789abcd"
READ_A = "read-a-key-0123456789abcde"
READ_ALL = "read-all-key-0123456789abc"
WRITE = "write-key-0123456789abcdef"
SCRAPER = "metrics-key-0123456789abcd"
KEYS = (
    f"{ADMIN}:admin; {ADMIN_A}:admin:tenanta; {READ_A}:read:-,tenanta; {READ_ALL}:read; "
    f"{WRITE}:write; {SCRAPER}:metrics"
)
ENTITIES = "/ngsi-ld/v1/temporal/entities"


def key(value: str, **headers: str) -> dict[str, str]:
    return {"X-Api-Key": value, **headers}


def note(eid: str, typ: str = "Robot") -> dict:
    return {
        "data": [
            {
                "id": eid,
                "type": typ,
                "TimeInstant": {"type": "DateTime", "value": "2024-05-01T00:00:00Z"},
                "battery": {"type": "Number", "value": 80},
            }
        ]
    }


@pytest.fixture
def secured(client_factory, store_url):
    """Two tenants with data, and a refused notification in each."""
    with client_factory(store_url, api_keys=KEYS) as client:
        for tenant in ("tenanta", "tenantb"):
            stored = client.post(
                "/v2/notify", json=note(f"urn:{tenant}:r1"), headers=key(ADMIN, **{"Fiware-Service": tenant})
            )
            assert stored.status_code == 200, stored.text
            refused = client.post("/v2/notify", json={"nope": 1}, headers=key(ADMIN, **{"Fiware-Service": tenant}))
            assert refused.status_code == 400
        yield client


@pytest.mark.parametrize("query", ["service=tenantb", "%73ervice=tenantb", "s%65rvice=tenantb&service=tenanta"])
def test_grafana_service_parameter_is_authorised_as_parsed(secured, query):
    got = secured.get(f"/grafana/infinity/entities?{query}", headers=key(READ_A))
    assert got.status_code == 403, got.text
    own = secured.get("/grafana/infinity/entities?%73ervice=tenanta", headers=key(READ_A))
    assert own.status_code == 200 and [row["entity"] for row in own.json()] == ["urn:tenanta:r1"], own.text


def test_routes_authorise_the_tenant_they_parse():
    """Behind the guard, the route refuses on its own parsed value too."""
    caller = Principal("k", frozenset({"read"}), frozenset({"tenanta"}))

    def request(query: bytes, headers=()) -> Request:
        scope = {"type": "http", "method": "GET", "path": "/", "query_string": query, "headers": list(headers)}
        scope[PRINCIPAL] = caller
        return Request(scope)

    assert grafana_scope(request(b"%73ervice=tenanta")).tenant == "tenanta"
    with pytest.raises(Forbidden):
        grafana_scope(request(b"%73ervice=tenantb"))
    with pytest.raises(Forbidden):
        tenant_of(request(b"", [(b"fiware-service", b"TenantB")]))
    assert tenant_of(request(b"", [(b"ngsild-tenant", b"TenantA")])) == "tenanta"


def test_all_tenants_needs_a_credential_restricted_to_no_tenant(secured):
    mine = key(ADMIN_A, **{"Fiware-Service": "tenanta"})  # a tenant it may touch, so the guard lets it by
    refused = secured.get("/v2/notify/rejected", params={"allTenants": "true"}, headers=mine)
    assert refused.status_code == 403, refused.text
    for spelling in ("1", "yes", "on", "True"):
        assert secured.get(f"/v2/notify/rejected?allTenants={spelling}", headers=mine).status_code == 403
    own = secured.get("/v2/notify/rejected", headers=mine)
    assert own.status_code == 200 and {row["tenant"] for row in own.json()} == {"tenanta"}
    every = secured.get("/v2/notify/rejected", params={"allTenants": "true"}, headers=key(ADMIN))
    assert every.status_code == 200 and {row["tenant"] for row in every.json()} == {"tenanta", "tenantb"}


def test_explorer_tenants_lists_only_what_the_key_may_see(secured):
    mine = secured.get("/ui/tenants", headers=key(READ_A))
    assert mine.status_code == 200 and [t["tenant"] for t in mine.json()] == ["tenanta"], mine.text
    every = secured.get("/ui/tenants", headers=key(READ_ALL))
    assert sorted(t["tenant"] for t in every.json()) == ["tenanta", "tenantb"]


def test_metrics_needs_a_key_that_may_see_every_tenant(secured):
    assert secured.get("/metrics", headers=key(READ_A)).status_code == 403
    assert secured.get("/metrics", headers=key(WRITE)).status_code == 403
    for allowed in (READ_ALL, SCRAPER, ADMIN):
        got = secured.get("/metrics", headers=key(allowed))
        assert got.status_code == 200 and 'tenant="tenantb"' in got.text, allowed
    assert secured.get("/v2/entities", headers=key(SCRAPER)).status_code == 403  # metrics reads no data


def test_changing_history_needs_admin_whatever_the_verb(secured):
    eid = "urn:ngsi-ld:Vehicle:1"
    body = {
        "id": eid,
        "type": "Vehicle",
        "speed": [{"type": "Property", "value": 1, "observedAt": "2024-05-01T00:00:00Z"}],
    }
    assert secured.post(ENTITIES, json=body, headers=key(WRITE)).status_code == 201
    [instance] = secured.get(f"{ENTITIES}/{eid}", headers=key(READ_ALL)).json()["speed"]
    url = f"{ENTITIES}/{eid}/attrs/speed/{instance['instanceId']}"  # sequential: guessable
    refused = secured.patch(url, json={"speed": {"type": "Property", "value": "urn:ngsi-ld:null"}}, headers=key(WRITE))
    assert refused.status_code == 403, refused.text
    assert secured.delete(url, headers=key(WRITE)).status_code == 403
    got = secured.get(f"{ENTITIES}/{eid}", headers=key(READ_ALL)).json()
    assert [i["value"] for i in got["speed"]] == [1]  # unchanged
    patch = {"speed": {"type": "Property", "value": 2}}
    assert secured.patch(url, json=patch, headers=key(ADMIN)).status_code == 204


def test_an_unknown_tenant_reads_like_an_empty_one(secured):
    """With authentication on, NonexistentTenant would tell which tenants exist."""

    def answers(tenant: str) -> list:
        h = key(READ_ALL, **{"NGSILD-Tenant": tenant})
        out = [secured.get(ENTITIES, params={"type": "Nothing"}, headers=h)]
        out.append(secured.get(f"{ENTITIES}/urn:ngsi-ld:X:1", headers=h))
        h = key(ADMIN, **{"NGSILD-Tenant": tenant})
        out.append(secured.delete(f"{ENTITIES}/urn:ngsi-ld:X:1", headers=h))
        return [(r.status_code, r.json() if r.content else None) for r in out]

    assert answers("tenanta") == answers("nosuchtenant")
    assert answers("nosuchtenant")[0] == (200, [])
    assert answers("nosuchtenant")[1][1]["type"].endswith("/ResourceNotFound")


def test_without_authentication_an_unknown_tenant_is_still_named(client):
    got = client.get(ENTITIES, params={"type": "Nothing"}, headers={"NGSILD-Tenant": "nosuchtenant"})
    assert got.status_code == 404 and got.json()["type"].endswith("/NonexistentTenant")
