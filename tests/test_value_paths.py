"""Value paths: ``attr(key.key[n])`` parsing, extraction, and use over HTTP."""

from __future__ import annotations

import pytest

from tsdb_service.core.errors import BadRequest
from tsdb_service.core.query import ValuePath
from tsdb_service.history.valuepath import extract, parse_attr_list, parse_value_path


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("temperature", ValuePath("temperature")),
        ("odom(twist.twist.linear.x)", ValuePath("odom", ("twist", "twist", "linear", "x"))),
        ("odom(pose.covariance[3])", ValuePath("odom", ("pose", "covariance", 3))),
        ("scan([0])", ValuePath("scan", (0,))),
        ("scan([0][1].a)", ValuePath("scan", (0, 1, "a"))),
        ("navigationState(data)", ValuePath("navigationState", ("data",))),
        ("a-b_c:d(k-1.k_2)", ValuePath("a-b_c:d", ("k-1", "k_2"))),
        ("urn:ngsi-ld:x(é.ü)", ValuePath("urn:ngsi-ld:x", ("é", "ü"))),
    ],
)
def test_parse(text, expected):
    assert parse_value_path(text) == expected
    assert parse_value_path(text).text == text


@pytest.mark.parametrize(
    "text",
    [
        "odom(",
        "odom()",
        "odom(.x)",
        "odom(x.)",
        "odom(x..y)",
        "odom(x[)",
        "odom(x[a])",
        "odom(x)(y)",
        "(x)",
        "odom(x y)",
        "odom(x)y",
        "te mp",
        "a=b",
        "a;b",
        "a'b",
        'a"b',
        "odom(x[1]y)",
        "a<b",
        "x" * 300,
        "odom(" + ".".join(["k"] * 40) + ")",
    ],
)
def test_rejects(text):
    with pytest.raises(BadRequest):
        parse_value_path(text)


def test_cannot_be_confused_with_an_attribute():
    # NGSIv2 attribute names may not contain '(' or ')': whatever has them is a path.
    assert parse_value_path("odom").steps == ()
    assert parse_value_path("odom(x)").attr == "odom"


def test_attr_list():
    assert parse_attr_list(None) is None
    assert parse_attr_list(" , ,") is None
    assert parse_attr_list("a, odom(x.y),a") == (ValuePath("a"), ValuePath("odom", ("x", "y")))


@pytest.mark.parametrize(
    ("steps", "expected"),
    [
        (("a", "b"), 1),
        (("a", "c", 1), 3),
        (("a", "c", 5), None),
        (("a", "missing"), None),
        (("a", "b", "deeper"), None),
        ((0,), None),
        (("n",), None),
        (("a",), {"b": 1, "c": [2, 3]}),
    ],
)
def test_extract(steps, expected):
    value = {"a": {"b": 1, "c": [2, 3]}, "n": None}
    assert extract(value, steps) == expected


ODOM = {
    "pose": {"pose": {"position": {"x": 1.0, "y": 2.0}}},
    "twist": {"twist": {"linear": {"x": 0.5}, "angular": {"z": 0.1}}, "covariance": [0.0, 1.5]},
}


def _mower(t: str, x: float, state: int) -> dict:
    odom = {**ODOM, "twist": {**ODOM["twist"], "twist": {"linear": {"x": x}, "angular": {"z": 0.1}}}}
    return {
        "data": [
            {
                "id": "mower",
                "type": "Robot",
                "TimeInstant": {"type": "DateTime", "value": t},
                "odom": {"type": "nav_msgs/msg/Odometry", "value": odom},
                "navigationState": {"type": "std_msgs/msg/Int8", "value": {"data": state}},
                "label": {"type": "Text", "value": "north lawn"},
            }
        ]
    }


@pytest.fixture
def mower(client, notify):
    for _i, (t, x, s) in enumerate(
        [("2024-05-01T10:00:00Z", 0.5, 1), ("2024-05-01T10:00:30Z", 1.5, 3), ("2024-05-01T10:01:10Z", 1.0, 3)]
    ):
        notify(client, _mower(t, x, s))
    return client


def test_history_of_a_number_inside_a_message(mower):
    r = mower.get("/v2/entities/mower/attrs/odom(twist.twist.linear.x)")
    assert r.status_code == 200
    assert r.json()["values"] == [0.5, 1.5, 1.0]
    assert r.json()["attrName"] == "odom(twist.twist.linear.x)"


def test_aggregates_like_a_number(mower):
    r = mower.get("/v2/entities/mower/attrs/odom(twist.twist.linear.x)?aggrMethod=max&aggrPeriod=minute")
    assert r.json()["values"] == [1.5, 1.0]
    r = mower.get("/v2/entities/mower/attrs/navigationState(data)?aggrMethod=sum")
    assert r.json()["values"] == [7]  # integers stay integers
    r = mower.get("/v2/entities/mower/attrs/odom(twist.covariance[1])?aggrMethod=avg")
    assert r.json()["values"] == [1.5]


def test_paths_and_plain_attributes_together(mower):
    r = mower.get("/v2/entities/mower?attrs=label,odom(pose.pose.position.y),navigationState(data)&lastN=1")
    assert r.json()["attributes"] == [
        {"attrName": "label", "values": ["north lawn"]},
        {"attrName": "navigationState(data)", "values": [3]},
        {"attrName": "odom(pose.pose.position.y)", "values": [2.0]},
    ]


def test_non_numbers_inside_are_not_aggregable(mower):
    r = mower.get("/v2/entities/mower/attrs/odom(pose.pose)?aggrMethod=avg")
    assert r.status_code == 404
    assert r.json()["error"] == "AggrMethod cannot be applied"
    r = mower.get("/v2/entities/mower/attrs/odom(pose.pose)?aggrMethod=count")
    assert r.json()["values"] == [3]


def test_last_value(mower):
    r = mower.post("/v2/op/query", json={"entities": [{"id": "mower"}], "attrs": ["odom(twist.twist.linear.x)"]})
    assert r.json()[0]["odom(twist.twist.linear.x)"] == {"type": "Number", "value": 1.0}


def test_odd_keys_are_literal(client, notify):
    keys = ["a\\b", "*", "$", "a*b", "x/y", "~0", "{}", "a`b", "@", "?", "%"]
    value = {k: i for i, k in enumerate(keys)}
    notify(
        client,
        {
            "data": [
                {
                    "id": "E",
                    "type": "T",
                    "TimeInstant": {"type": "DateTime", "value": "2024-01-01T00:00:00Z"},
                    "o": {"type": "StructuredValue", "value": value},
                }
            ]
        },
    )
    from urllib.parse import quote

    for i, key in enumerate(keys):
        # In attrs= (any key), and in the URL path (a '/' would split the path).
        for extra, expected in (({}, [i]), ({"aggrMethod": "sum"}, [i]), ({"aggrMethod": "count"}, [1])):
            r = client.get("/v2/entities/E/value", params={"attrs": f"o({key})", **extra})
            assert r.status_code == 200, (key, extra, r.text)
            assert r.json()["attributes"] == [{"attrName": f"o({key})", "values": expected}], (key, extra, r.text)
            if "/" not in key:
                r = client.get(f"/v2/entities/E/attrs/{quote(f'o({key})', safe='()')}/value", params=extra)
                assert r.status_code == 200, (key, extra, r.text)
                assert r.json()["values"] == expected, (key, extra, r.text)
