"""SimpleJSON targets name entities and attributes that contain ``/``.

A target is ``<entity id>/<attribute or value path>``; ids (NGSI-LD URIs)
and attribute names may contain ``/`` themselves, so ``urn:a/b/v`` alone
could be ``urn:a`` + ``b/v`` or ``urn:a/b`` + ``v``. Inside either part
``%2F`` stands for ``/`` and ``%25`` for ``%`` (as in history URL paths);
``/search`` lists names in that form, and ``/query`` accepts them back.
"""

from __future__ import annotations

import pytest

H = {"Content-Type": "application/json", "Fiware-Service": "slashes"}
RANGE = {"from": "2025-06-02T08:00:00Z", "to": "2025-06-02T10:00:00Z"}
# (entity id, attribute, value): the first two read the same without escaping.
SERIES = [("urn:a/b", "v", 1), ("urn:a", "b/v", 2), ("p%2Fq", "v", 3), ("urn:plain", "v", 4)]
NAMES = ["p%252Fq/v", "urn:a%2Fb/v", "urn:a/b%2Fv", "urn:plain/v"]


@pytest.fixture
def loaded(client, notify):
    for eid, attr, value in SERIES:
        notify(
            client,
            {
                "subscriptionId": "s",
                "data": [
                    {
                        "id": eid,
                        "type": "T",
                        attr: {"type": "Number", "value": value},
                        "TimeInstant": {"type": "DateTime", "value": "2025-06-02T09:00:00.000Z"},
                    }
                ],
            },
            H,
        )
    return client


def _post(client, path: str, body: dict) -> list:
    response = client.post("/grafana/simplejson" + path, json=body, headers=H)
    assert response.status_code == 200, response.text
    return response.json()


def _names(client, path: str = "/search", body: dict | None = None) -> list[str]:
    """The metric names listed, less the TimeInstant every entity has."""
    found = _post(client, path, {"target": ""} if body is None else body)
    names = [n if isinstance(n, str) else n["value"] for n in found]
    return [n for n in names if not n.endswith("/TimeInstant")]


def _query(client, target: str, fmt: str = "table") -> list:
    body = {"range": RANGE, "targets": [{"refId": "A", "target": target, "payload": {"format": fmt}}]}
    return _post(client, "/query", body)


def test_search_lists_unambiguous_names(loaded):
    assert _names(loaded) == NAMES
    assert _names(loaded, "/metrics", {}) == NAMES


def test_every_listed_name_queries_back_its_own_series(loaded):
    expected = {name: (eid, value) for name, (eid, _, value) in zip(NAMES, sorted(SERIES, key=_listed), strict=True)}
    for name in _names(loaded):
        (table,) = _query(loaded, name)
        eid, value = expected[name]
        assert [row[1:] for row in table["rows"]] == [[eid, value]], name


def _listed(series: tuple) -> str:
    return NAMES[[("p%2Fq", "v"), ("urn:a/b", "v"), ("urn:a", "b/v"), ("urn:plain", "v")].index(series[:2])]


def test_entity_variables_are_in_target_form(loaded):
    entities = _post(loaded, "/search", {"target": "entities"})
    assert entities == ["p%252Fq", "urn:a", "urn:a%2Fb", "urn:plain"]
    assert _post(loaded, "/search", {"target": "attrs:urn:a%2Fb"}) == ["TimeInstant", "v"]
    assert _post(loaded, "/search", {"target": "attrs:urn:a"}) == ["TimeInstant", "b%2Fv"]
    # "$entity/$attr" built from variable values is a valid target again
    (table,) = _query(loaded, f"{entities[2]}/v")
    assert [row[1:] for row in table["rows"]] == [["urn:a/b", 1]]
    texts = {v["__value"]: v["__text"] for v in _post(loaded, "/variable", {"payload": {"target": "entities"}})}
    assert texts["urn:a%2Fb"] == "a/b"


def test_plain_targets_still_split_at_the_first_slash(loaded):
    (table,) = _query(loaded, "urn:a/b/v")  # urn:a's attribute "b/v"
    assert [row[1:] for row in table["rows"]] == [["urn:a", 2]]
    (series,) = _query(loaded, "urn:plain/v", "timeseries")
    assert series["datapoints"] == [[4, 1748854800000]]


def test_annotations_and_payload_options_take_escaped_ids(loaded):
    body = {"range": RANGE, "annotation": {"name": "x", "query": "urn:a%2Fb/v=1"}}
    (event,) = _post(loaded, "/annotations", body)
    assert event["text"].startswith("v = 1") and event["text"].endswith(" on urn:a/b"), event["text"]
    options = _post(loaded, "/metric-payload-options", {"metric": "urn:a%2Fb/v", "name": "path"})
    assert options == []  # a number has no path inside; the metric itself was found without error
