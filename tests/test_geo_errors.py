"""Bad geo-queries get 400 in the NGSI error shape, saying what is wrong; never 500.

Every endpoint that takes ``georel``/``geometry``/``coords`` is checked with
every mistake; then ~100 seeded random parameter combinations (valid, odd and
broken) run against a store holding unusual geometries (collections, 3D,
multipolygons, the poles and the antimeridian), so the matching code runs too.
"""

from __future__ import annotations

import random
from urllib.parse import quote

import pytest

T0 = "2024-05-01T10:00:00.000Z"

ENDPOINTS = [
    "/v2/entities",
    "/v2/entities/sol",
    "/v2/entities/sol/value",
    "/v2/entities/sol/attrs/temperature",
    "/v2/entities/sol/attrs/temperature/value",
    "/v2/types/Sensor",
    "/v2/types/Sensor/value",
    "/v2/types/Sensor/attrs/temperature",
    "/v2/types/Sensor/attrs/temperature/value",
    "/v2/attrs",
    "/v2/attrs/value",
    "/v2/attrs/temperature",
    "/v2/attrs/temperature/value",
]

SQUARE = "40,-4;40,-3;41,-3;41,-4;40,-4"

# (case id, query parameters, words the description must contain)
BAD = [
    (
        "coords-not-numbers",
        {"georel": "coveredBy", "geometry": "point", "coords": "abc,def"},
        ["coords", "'abc,def'", "not two numbers"],
    ),
    (
        "coords-half-number",
        {"georel": "coveredBy", "geometry": "point", "coords": "40.4,x"},
        ["coords", "not two numbers"],
    ),
    (
        "coords-three-numbers",
        {"georel": "near;maxDistance:10", "geometry": "point", "coords": "40,-3,5"},
        ["coords", "'40,-3,5'", "lat,lon"],
    ),
    (
        "coords-one-number",
        {"georel": "near;maxDistance:10", "geometry": "point", "coords": "40"},
        ["coords", "lat,lon"],
    ),
    (
        "coords-trailing-semicolon",
        {"georel": "intersects", "geometry": "line", "coords": "40,-4;41,-3;"},
        ["coords point 3", "lat,lon"],
    ),
    (
        "coords-lat-above-90",
        {"georel": "coveredBy", "geometry": "point", "coords": "90.5,0"},
        ["latitude", "90.5", "-90..90"],
    ),
    (
        "coords-lat-below-minus-90",
        {"georel": "coveredBy", "geometry": "box", "coords": "0,0;-91,10"},
        ["coords point 2", "latitude", "-90..90"],
    ),
    (
        "coords-lon-above-180",
        {"georel": "coveredBy", "geometry": "point", "coords": "0,180.5"},
        ["longitude", "180.5", "-180..180"],
    ),
    ("coords-nan", {"georel": "coveredBy", "geometry": "point", "coords": "nan,0"}, ["latitude", "nan"]),
    ("coords-inf", {"georel": "coveredBy", "geometry": "point", "coords": "0,inf"}, ["longitude", "inf"]),
    (
        "polygon-unclosed",
        {"georel": "coveredBy", "geometry": "polygon", "coords": "40,-4;40,-3;41,-3;41,-4"},
        ["polygon", "closed"],
    ),
    (
        "polygon-too-few-points",
        {"georel": "intersects", "geometry": "polygon", "coords": "40,-4;40,-3;40,-4"},
        ["polygon", "four points"],
    ),
    (
        "polygon-self-intersecting",
        {"georel": "intersects", "geometry": "polygon", "coords": "40,-4;40,-3;41,-4;41,-3;40,-4"},
        ["polygon", "not a valid polygon", "Self-intersection"],
    ),
    (
        "point-two-positions",
        {"georel": "equals", "geometry": "point", "coords": "40,-4;41,-3"},
        ["geometry=point", "exactly one"],
    ),
    (
        "line-one-position",
        {"georel": "intersects", "geometry": "line", "coords": "40,-4"},
        ["geometry=line", "two points"],
    ),
    ("box-one-corner", {"georel": "coveredBy", "geometry": "box", "coords": "40,-4"}, ["geometry=box", "two"]),
    (
        "box-three-corners",
        {"georel": "coveredBy", "geometry": "box", "coords": "40,-4;41,-3;42,-2"},
        ["geometry=box", "two"],
    ),
    ("box-flat", {"georel": "coveredBy", "geometry": "box", "coords": "40,-4;40,-3"}, ["geometry=box", "differ"]),
    ("georel-unknown", {"georel": "within", "geometry": "point", "coords": "40,-4"}, ["unknown georel", "'within'"]),
    (
        "georel-wrong-case",
        {"georel": "coveredby", "geometry": "point", "coords": "40,-4"},
        ["unknown georel", "coveredBy"],
    ),
    (
        "geometry-unknown",
        {"georel": "coveredBy", "geometry": "circle", "coords": "40,-4"},
        ["unknown geometry", "'circle'"],
    ),
    ("missing-coords", {"georel": "coveredBy", "geometry": "point"}, ["missing: coords"]),
    ("missing-geometry", {"georel": "coveredBy", "coords": "40,-4"}, ["missing: geometry"]),
    ("missing-georel", {"geometry": "point", "coords": "40,-4"}, ["missing: georel"]),
    ("missing-two", {"georel": "near;maxDistance:5"}, ["missing: geometry, coords"]),
    ("empty-coords", {"georel": "coveredBy", "geometry": "point", "coords": ""}, ["missing: coords"]),
    (
        "near-without-distance",
        {"georel": "near", "geometry": "point", "coords": "40,-4"},
        ["near", "maxDistance", "minDistance"],
    ),
    (
        "near-with-polygon",
        {"georel": "near;maxDistance:10", "geometry": "polygon", "coords": SQUARE},
        ["near", "geometry=point"],
    ),
    (
        "near-with-box",
        {"georel": "near;maxDistance:10", "geometry": "box", "coords": "40,-4;41,-3"},
        ["near", "geometry=point"],
    ),
    (
        "near-with-line",
        {"georel": "near;minDistance:10", "geometry": "line", "coords": "40,-4;41,-3"},
        ["near", "geometry=point"],
    ),
    (
        "near-min-above-max",
        {"georel": "near;maxDistance:10;minDistance:20", "geometry": "point", "coords": "40,-4"},
        ["minDistance 20", "greater", "maxDistance 10"],
    ),
    (
        "near-min-above-max-reversed",
        {"georel": "near;minDistance:20;maxDistance:10", "geometry": "point", "coords": "40,-4"},
        ["minDistance 20", "greater", "maxDistance 10"],
    ),
    (
        "near-distance-not-number",
        {"georel": "near;maxDistance:ten", "geometry": "point", "coords": "40,-4"},
        ["maxDistance", "'ten'"],
    ),
    (
        "near-distance-negative",
        {"georel": "near;minDistance:-1", "geometry": "point", "coords": "40,-4"},
        ["minDistance", "non-negative", "'-1'"],
    ),
    (
        "near-distance-infinite",
        {"georel": "near;maxDistance:1e999", "geometry": "point", "coords": "40,-4"},
        ["maxDistance", "'1e999'"],
    ),
    (
        "near-distance-empty",
        {"georel": "near;maxDistance:", "geometry": "point", "coords": "40,-4"},
        ["maxDistance", "''"],
    ),
    (
        "near-modifier-unknown",
        {"georel": "near;distance:10", "geometry": "point", "coords": "40,-4"},
        ["modifier", "'distance:10'"],
    ),
    (
        "near-modifier-twice",
        {"georel": "near;maxDistance:10;maxDistance:20", "geometry": "point", "coords": "40,-4"},
        ["maxDistance", "twice"],
    ),
    (
        "modifier-on-coveredBy",
        {"georel": "coveredBy;maxDistance:10", "geometry": "point", "coords": "40,-4"},
        ["coveredBy", "no modifiers"],
    ),
    (
        "geoScope-unknown",
        {"georel": "coveredBy", "geometry": "point", "coords": "40,-4", "geoScope": "row"},
        ["unknown geoScope", "'row'", "sample, entity"],
    ),
    ("geoScope-alone", {"geoScope": "entity"}, ["geoScope", "georel, geometry and coords"]),
]


def _query(params: dict) -> str:
    return "&".join(f"{k}={quote(v, safe=',;:')}" for k, v in params.items())


@pytest.fixture(scope="module")
def geo_client(client_factory, store_url_factory, notify):
    """A small store with ordinary and unusual geometries."""
    locations = {
        "sol": {"type": "geo:json", "value": {"type": "Point", "coordinates": [-3.7038, 40.4168]}},
        "tower": {"type": "geo:json", "value": {"type": "Point", "coordinates": [-3.6883, 40.4775, 250.0]}},
        "pole": {"type": "geo:point", "value": "90, 0"},
        "south-pole": {"type": "geo:point", "value": "-90, 180"},
        "dateline": {"type": "geo:line", "value": ["-16.5, 179.9", "-17.5, -179.9"]},
        "fc": {
            "type": "geo:json",
            "value": {
                "type": "FeatureCollection",
                "features": [
                    {"type": "Feature", "geometry": {"type": "Point", "coordinates": [-3.70, 40.41]}, "properties": {}},
                    {
                        "type": "Feature",
                        "geometry": {
                            "type": "Polygon",
                            "coordinates": [[[-3.71, 40.41], [-3.70, 40.41], [-3.70, 40.42], [-3.71, 40.41]]],
                        },
                        "properties": {},
                    },
                ],
            },
        },
        "multi": {
            "type": "geo:json",
            "value": {
                "type": "MultiPolygon",
                "coordinates": [[[[0, 0], [1, 0], [1, 1], [0, 1], [0, 0]]], [[[2, 0], [3, 0], [3, 1], [2, 1], [2, 0]]]],
            },
        },
        "gc": {
            "type": "geo:json",
            "value": {
                "type": "GeometryCollection",
                "geometries": [
                    {"type": "Point", "coordinates": [10, 10]},
                    {"type": "LineString", "coordinates": [[10, 10], [11, 11]]},
                ],
            },
        },
        "huge": {"type": "geo:box", "value": ["-80, -170", "80, 170"]},
        "still": {"type": "geo:line", "value": ["41.0, 1.0", "41.0, 1.0"]},  # a line that is a point
        "not-geo": {"type": "geo:point", "value": "somewhere"},  # stored as text, not a location
    }
    with client_factory(store_url_factory("geo-errors")) as client:
        for i, (eid, location) in enumerate(locations.items()):
            notify(
                client,
                {
                    "subscriptionId": "geo-errors",
                    "data": [
                        {
                            "id": eid,
                            "type": "Sensor",
                            "TimeInstant": {"type": "DateTime", "value": T0},
                            "location": location,
                            "temperature": {"type": "Number", "value": float(i)},
                        }
                    ],
                },
            )
        yield client


def assert_bad_request(response, words: list[str]) -> None:
    assert response.status_code == 400, (response.status_code, response.text)
    body = response.json()
    assert set(body) == {"error", "description"}, body
    assert body["error"] == "BadRequest", body
    for word in words:
        assert word in body["description"], (word, body["description"])


@pytest.mark.parametrize(("params", "words"), [pytest.param(p, w, id=name) for name, p, w in BAD])
def test_bad_geo_query(geo_client, params, words):
    assert_bad_request(geo_client.get(f"/v2/entities?{_query(params)}"), words)


@pytest.mark.parametrize("endpoint", ENDPOINTS)
def test_every_endpoint_rejects_bad_geo(geo_client, endpoint):
    for name, params, words in BAD:
        response = geo_client.get(f"{endpoint}?{_query(params)}")
        assert response.status_code == 400, (name, response.text)
        assert_bad_request(response, words)


def test_python_only_number_spellings_are_not_coords(geo_client):
    """``float()`` accepts ``1_0`` as 10; NGSI coords are JSON-like numbers.
    encodings.py already refuses it for stored ``geo:point`` text."""
    query = _query({"georel": "coveredBy", "geometry": "point", "coords": "4_0,-3"})
    assert_bad_request(geo_client.get(f"/v2/entities?{query}"), ["coords", "'4_0,-3'"])


def test_all_three_empty_is_no_filter(geo_client):
    everything = geo_client.get("/v2/entities").json()
    assert geo_client.get("/v2/entities?georel=&geometry=&coords=").json() == everything


@pytest.mark.parametrize(
    ("params", "expected"),
    [
        pytest.param(
            {"georel": "near;maxDistance:1000", "geometry": "point", "coords": "90,0"}, {"pole"}, id="north-pole"
        ),
        pytest.param(
            {"georel": "near;maxDistance:1000", "geometry": "point", "coords": "-90,-180"},
            {"south-pole"},
            id="south-pole-other-lon",
        ),
        # (the huge box's distance here is pinned in test_geo_queries.py::test_near_to_large_shapes)
        pytest.param(
            {
                "georel": "near;maxDistance:100000",
                "geometry": "point",
                "coords": "-17,180",
                "type": "Sensor",
                "idPattern": "^date",
            },
            {"dateline"},
            id="antimeridian",
        ),
        pytest.param(
            {"georel": "near;maxDistance:0", "geometry": "point", "coords": "40.4168,-3.7038"},
            {"sol", "huge"},
            id="max-distance-0",
        ),
        pytest.param(
            {"georel": "near;minDistance:0;maxDistance:40000000", "geometry": "point", "coords": "0,0"},
            {"sol", "tower", "pole", "south-pole", "dateline", "fc", "multi", "gc", "huge", "still"},
            id="whole-earth",
        ),
        pytest.param(
            {"georel": "near;maxDistance:100", "geometry": "point", "coords": "41.0005,1.0"},
            {"still", "huge"},
            id="line-of-one-point",
        ),
        pytest.param(
            {"georel": "near;maxDistance:100", "geometry": "point", "coords": "41.0005,1.0", "geoScope": "entity"},
            {"still", "huge"},
            id="line-of-one-point-entity-scope",
        ),
        pytest.param(
            {"georel": "near;maxDistance:1", "geometry": "point", "coords": "40.4775,-3.6883"},
            {"tower", "huge"},
            id="3d-point",
        ),
        pytest.param(
            {"georel": "coveredBy", "geometry": "box", "coords": "40.40,-3.72;40.43,-3.69"},
            {"sol", "fc"},
            id="feature-collection",
        ),
        pytest.param(
            {"georel": "intersects", "geometry": "point", "coords": "0.5,2.5"}, {"multi", "huge"}, id="multipolygon"
        ),
        pytest.param(
            {"georel": "intersects", "geometry": "line", "coords": "10.5,10;10.5,11"},
            {"gc", "huge"},
            id="geometry-collection",
        ),
        pytest.param(
            {"georel": "equals", "geometry": "box", "coords": "-80,-170;80,170"}, {"huge"}, id="equals-huge-box"
        ),
    ],
)
def test_unusual_but_valid(geo_client, params, expected):
    response = geo_client.get(f"/v2/entities?{_query(params)}")
    assert response.status_code == 200, response.text
    assert {e["id"] for e in response.json()} == expected


# --- fuzz ----------------------------------------------------------------------------------------

GEORELS = [
    "near;maxDistance:1000",
    "near;minDistance:5",
    "near;maxDistance:0;minDistance:0",
    "near;minDistance:1e3;maxDistance:2e7",
    "near;maxDistance:1e308",
    "near",
    "near;",
    "near;maxDistance",
    "near;maxDistance:1000;",
    "coveredBy",
    "intersects",
    "equals",
    "disjoint",
    "disjoint;",
    "COVEREDBY",
    "",
    " near;maxDistance:5 ",
    "near;maxDistance:5;minDistance:6",
    "near;minDistance:-0",
    "near;maxDistance:0x10",
    "within",
    "near;maxDistance:NaN",
    "near;;maxDistance:3",
    "near;maxDistance:1;minDistance:1",
    "%",
    "near;maxDistance:5:6",
    "\u00e9",
    "near;maxDistance:\u0661",
]
GEOMETRIES = ["point", "line", "polygon", "box", "", "Point", "circle", "multipoint", " point", "box;", "\x00"]


def _number(rng: random.Random) -> str:
    return rng.choice(
        [
            f"{rng.uniform(-90, 90):.5f}",
            f"{rng.uniform(-180, 180):.6f}",
            str(rng.randint(-200, 200)),
            "90",
            "-90",
            "180",
            "-180",
            "0",
            "-0",
            "1e2",
            "1e400",
            "nan",
            "inf",
            "-inf",
            "",
            " ",
            "x",
            "1.2.3",
            "0x1A",
            "\u0661",
            "9" * 400,
            "1e-400",
            "+5",
            "--5",
            "5.",
            ".5",
        ]
    )


def _coords(rng: random.Random) -> str:
    kind = rng.random()
    if kind < 0.15:
        return rng.choice(
            [
                "",
                ";",
                ",",
                ";;",
                "40,-4;",
                ";40,-4",
                "40;-4",
                "[40,-4]",
                "40 -4",
                "40,-4,0;1,2",
                SQUARE,
                "40,-4;40,-4",
                "0,0;0,0;0,0;0,0",
                "40,-4;41,-4;40,-4;41,-4;40,-4",
            ]
        )
    n = rng.choice([1, 1, 2, 2, 3, 4, 5, 6, 50])
    points = [
        f"{_number(rng)},{_number(rng)}"
        if rng.random() < 0.8
        else f"{rng.uniform(-60, 60):.4f},{rng.uniform(-120, 120):.4f}"
        for _ in range(n)
    ]
    if n >= 4 and rng.random() < 0.6:
        points[-1] = points[0]  # closed ring, maybe valid
    return ";".join(points)


def _fuzz_params(count: int = 100) -> list:
    rng = random.Random(20240501)
    cases = []
    for i in range(count):
        params = {}
        if rng.random() < 0.9:
            params["georel"] = rng.choice(GEORELS)
        if rng.random() < 0.9:
            params["geometry"] = rng.choice(GEOMETRIES)
        if rng.random() < 0.9:
            params["coords"] = _coords(rng)
        if rng.random() < 0.3:
            params[rng.choice(["lastN", "toDate", "fromDate", "limit", "attrs"])] = rng.choice(
                ["2", "2024-05-01T10:00:00Z", "2030-01-01T00:00:00Z", "location", "temperature"]
            )
        cases.append(pytest.param(rng.choice(ENDPOINTS), params, id=f"fuzz{i:03d}"))
    return cases


@pytest.mark.parametrize(("endpoint", "params"), _fuzz_params())
def test_fuzz_never_500(geo_client, endpoint, params):
    query = "&".join(f"{quote(k)}={quote(v, safe='')}" for k, v in params.items())
    response = geo_client.get(f"{endpoint}?{query}")
    assert response.status_code < 500, (params, response.text)
    if response.status_code >= 400:
        body = response.json()
        assert set(body) == {"error", "description"} and body["description"], body
