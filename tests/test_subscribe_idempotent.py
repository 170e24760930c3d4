"""``tsdb-service subscribe`` creates a use case's subscription once.

Running it twice must not leave two Orion subscriptions (every sample would
be stored twice): it lists the broker's subscriptions for the tenant and
service path and keeps an equivalent one (same notify URL, same entities);
``--force`` creates anyway. The broker is the stand-in of
test_subscribe_api over real HTTP, answering the listing the way Orion
does: paged, with ``Fiware-Total-Count`` under ``options=count`` and the
fields Orion adds (``status``, ``timesSent``, ``condition``).
"""

from __future__ import annotations

from urllib.parse import urlsplit

import pytest
from starlette.requests import Request
from starlette.responses import JSONResponse, PlainTextResponse, Response
from starlette.routing import Route

from tests.support.server import free_port
from tests.support.standins import StandInBroker, served
from tsdb_service.broker.subscriptions import default_notify_url, subscription
from tsdb_service.cli.main import main
from tsdb_service.usecases.registry import SIMULATORS

MOWER = SIMULATORS["lawnmower"]
TENANT = (MOWER.tenancy.service, MOWER.tenancy.service_path)
NOTIFY = "http://tsdb-service:8668/v2/notify"


class PagingBroker(StandInBroker):
    """Pages of at most ``page`` subscriptions, shaped as Orion lists them."""

    page = 10

    def __init__(self) -> None:
        super().__init__()
        self.listing_fails = False
        self.app.router.routes.insert(0, Route("/v2/subscriptions", self.paged, methods=["GET"]))

    async def paged(self, request: Request) -> Response:
        if self.listing_fails:
            return PlainTextResponse("database down", status_code=500)
        subs = [_as_orion_lists(s) for s in self.subscriptions.get(self.tenant(request), [])]
        offset = int(request.query_params.get("offset", 0))
        limit = min(int(request.query_params.get("limit", 20)), self.page)
        headers = {"Fiware-Total-Count": str(len(subs))} if "count" in request.query_params.get("options", "") else {}
        return JSONResponse(subs[offset : offset + limit], headers=headers)


def _as_orion_lists(sub: dict) -> dict:
    notification = {
        **sub["notification"],
        "attrs": [],
        "onlyChangedAttrs": False,
        "timesSent": 12,
        "lastNotification": "2025-06-02T09:00:00.000Z",
        "covered": False,
    }
    subject = {**sub["subject"], "condition": {"attrs": [], "notifyOnMetadataChange": True}}
    return {**sub, "status": "active", "subject": subject, "notification": notification}


@pytest.fixture
def broker():
    with served(PagingBroker()) as stand_in:
        yield stand_in


def _subscribe(broker, *extra: str) -> int:
    url = [] if "--notify-url" in extra else ["--notify-url", NOTIFY]
    return main(["subscribe", "--broker", broker.url, "--use-case", "lawnmower", *url, *extra])


def _seed(broker, tenant, document) -> None:
    broker.subscriptions.setdefault(tenant, []).append(
        {"id": f"seeded{len(broker.subscriptions.get(tenant, []))}", **document}
    )


def test_running_twice_creates_one_subscription(broker, capsys):
    assert _subscribe(broker) == 0
    assert "201 Created" in capsys.readouterr().out
    assert _subscribe(broker) == 0
    out = capsys.readouterr().out
    sub_id = broker.subscriptions[TENANT][0]["id"]
    assert "already subscribed" in out and sub_id in out and "status active" in out and "--force" in out, out
    assert len(broker.subscriptions[TENANT]) == 1


def test_force_creates_another(broker, capsys):
    assert _subscribe(broker) == 0
    assert _subscribe(broker, "--force") == 0
    assert "201 Created" in capsys.readouterr().out.splitlines()[-1]
    assert len(broker.subscriptions[TENANT]) == 2


def test_an_equivalent_subscription_past_the_first_page_is_found(broker):
    other = subscription(MOWER, "http://elsewhere:8668/v2/notify")
    for _ in range(25):
        _seed(broker, TENANT, other)
    _seed(broker, TENANT, {**subscription(MOWER, NOTIFY), "description": "made by hand"})
    assert _subscribe(broker) == 0
    assert len(broker.subscriptions[TENANT]) == 26


@pytest.mark.parametrize("change", ["url", "entities", "service path", "tenant"])
def test_what_is_not_equivalent_does_not_count(broker, change):
    document, tenant = subscription(MOWER, NOTIFY), TENANT
    if change == "url":
        document = subscription(MOWER, "http://elsewhere:8668/v2/notify")
    elif change == "entities":
        document = {**document, "subject": {"entities": [{"idPattern": ".*"}]}}
    elif change == "service path":
        tenant = (TENANT[0], "/elsewhere")
    else:
        tenant = ("another", TENANT[1])
    _seed(broker, tenant, document)
    assert _subscribe(broker) == 0
    created = [s for s in broker.subscriptions[TENANT] if not s["id"].startswith("seeded")]
    assert len(created) == 1


def test_a_broker_that_cannot_list_gets_nothing(broker, capsys):
    broker.listing_fails = True
    assert _subscribe(broker) == 1
    out = capsys.readouterr().out
    assert "500" in out and "database down" in out and "nothing created" in out, out
    assert TENANT not in broker.subscriptions
    assert _subscribe(broker, "--force") == 0
    assert len(broker.subscriptions[TENANT]) == 1


def test_the_same_notify_url_option_is_what_is_compared(broker):
    url = "http://qa:8668/v2/notify"
    for _ in range(2):
        assert _subscribe(broker, "--notify-url", url) == 0
    (only,) = broker.subscriptions[TENANT]
    assert only["notification"]["http"]["url"] == url


def test_the_default_notify_url_is_this_machine_and_is_printed(broker, capsys):
    """It was http://tsdb-service:8668/v2/notify, a name only docker-compose.yml's network resolves."""
    assert main(["subscribe", "--broker", broker.url, "--use-case", "lawnmower"]) == 0
    first = capsys.readouterr().out.splitlines()[0]
    (made,) = broker.subscriptions[TENANT]
    url = made["notification"]["http"]["url"]
    assert first == f"notify URL: {url} (this machine as the broker reaches it; --notify-url to choose)"
    assert url == default_notify_url(broker.url) and url.endswith(":8668/v2/notify")
    assert urlsplit(url).hostname not in ("tsdb-service", "localhost", "127.0.0.1")


def test_a_given_notify_url_is_printed_as_given(broker, capsys):
    assert _subscribe(broker, "--notify-url", "http://qa:8668/v2/notify") == 0
    assert capsys.readouterr().out.splitlines()[0] == "notify URL: http://qa:8668/v2/notify"


def test_an_unreachable_broker_gets_no_force_hint(capsys):
    """--force cannot help a broker nobody answers at."""
    url = f"http://127.0.0.1:{free_port()}"
    assert main(["subscribe", "--broker", url, "--use-case", "lawnmower", "--notify-url", NOTIFY]) == 1
    out = capsys.readouterr().out
    assert f"could not reach {url}/v2/subscriptions" in out and "nothing created" in out
    assert "--force" not in out
