"""Content-Type: every JSON type a broker uses is a notification; the types a
browser may send cross-site without a preflight are refused (415), and the
refused notification is kept whole with advice on fixing the subscription."""

from __future__ import annotations

import json
from pathlib import Path

import orjson
import pytest

PAYLOADS = Path(__file__).parent / "payloads"
BODY = {"subscriptionId": "s", "data": [{"id": "E", "type": "T", "temperature": {"type": "Number", "value": 21.5}}]}

ACCEPTED = [
    "application/json",
    "application/json; charset=utf-8",
    "Application/JSON;charset=UTF-8",
    "application/ld+json",
    "application/ld+json; charset=utf-8",
    "application/geo+json",
    " application/json ",
    "application/vnd.example+json",
]
# The "simple" request types of the Fetch standard (no CORS preflight), and
# other non-JSON types.
REFUSED = [
    "text/plain",
    "text/plain; charset=utf-8",
    "application/x-www-form-urlencoded",
    "multipart/form-data; boundary=x",
    None,
    "",
    "text/json",
    "application/xml",
    "application/jsonp",
]


@pytest.mark.parametrize("path", ["/v2/notify", "/ngsi-ld/v1/notify"])
@pytest.mark.parametrize("media", ACCEPTED)
def test_json_media_types_are_notifications(client, media, path):
    response = client.post(path, content=orjson.dumps(BODY), headers={"Content-Type": media})
    assert response.status_code == 200, response.text


@pytest.mark.parametrize("media", REFUSED)
def test_simple_request_types_are_refused_and_kept(client, media):
    headers = {"Fiware-Service": "media"} | ({} if media is None else {"Content-Type": media})
    raw = orjson.dumps(BODY)
    response = client.post("/v2/notify", content=raw, headers=headers)
    assert response.status_code == 415, response.text
    error = response.json()
    assert error["error"] == "UnsupportedMediaType"
    assert "httpCustom" in error["description"] and "application/json" in error["description"]
    [kept] = client.get("/v2/notify/rejected", headers={"Fiware-Service": "media"}).json()
    assert kept["body"] == raw.decode() and kept["bodySize"] == len(raw) and not kept["bodyTruncated"]
    assert kept["description"] == error["description"]
    assert client.get("/v2/entities", headers={"Fiware-Service": "media"}).json() == []


@pytest.mark.parametrize("name", ["text_plain_payload", "header_override"])
def test_orion_custom_notifications_are_kept_whole(client, name):
    record = json.loads((PAYLOADS / "orion-custom" / f"{name}.json").read_text())
    response = client.post("/v2/notify", content=record["bodyText"].encode(), headers=record["headers"])
    assert response.status_code == record["expect"]["status"]
    [kept] = client.get("/v2/notify/rejected", headers={"Fiware-Service": "custom"}).json()
    assert kept["body"] == record["bodyText"]
    assert kept["headers"]["content-type"] == record["headers"]["Content-Type"]
    assert kept["headers"]["fiware-correlator"] == record["headers"]["Fiware-Correlator"]
