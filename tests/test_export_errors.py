"""``GET /v2/export``: bad input is a 400 in the NGSI shape, before any byte of a file."""

from __future__ import annotations

import pytest

from tests.export_fixtures import READ

BAD = [
    pytest.param({"format": "xlsx"}, READ, "format must be csv, parquet or mcap", id="format"),
    pytest.param({"fromdate": "2024-01-01"}, READ, "unknown parameter 'fromdate'", id="unknown-parameter"),
    pytest.param({"lastN": "3"}, READ, "unknown parameter 'lastN'", id="history-only-parameter"),
    pytest.param({"attrs": "odom(twist.linear.x)"}, READ, "not value paths", id="value-path"),
    pytest.param({"attrs": "bad name"}, READ, "invalid attribute name", id="attr-name"),
    pytest.param({"fromDate": "yesterday"}, READ, "fromDate must be an ISO 8601", id="from-date"),
    pytest.param({"toDate": "2024-13-01"}, READ, "toDate must be an ISO 8601", id="to-date"),
    pytest.param({"idPattern": "("}, READ, "idPattern is not a valid regular expression", id="id-pattern"),
    pytest.param({}, {"Fiware-Service": "no-dashes!"}, "invalid tenant", id="tenant"),
    pytest.param({}, {"Fiware-ServicePath": "site"}, "must start with '/'", id="service-path"),
]


@pytest.mark.parametrize(("params", "headers", "says"), BAD)
def test_bad_input_is_a_clear_400(client, params, headers, says):
    response = client.get("/v2/export", params=params, headers=headers)
    assert response.status_code == 400, response.text
    assert response.headers["content-type"] == "application/json"
    body = response.json()
    assert set(body) == {"error", "description"}
    assert says in body["description"]
