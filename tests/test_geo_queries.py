"""Golden tests of NGSIv2 geo-queries (issue 4): every georel x geometry.

One dataset, loaded once per backend, of real places stored in every NGSI
location encoding:

* Madrid: points (``geo:json``, ``geo:point`` text, NGSI-LD ``GeoProperty``
  from an NGSI-LD notification), Gran Via as a ``geo:line``, the centre as a
  ``geo:polygon``, Retiro park as a ``geo:box`` and Plaza Mayor as a
  ``geo:json`` Polygon;
* Barcelona: one point, far from everything;
* Helsinki (~60°N): points at chosen geodesic distances from the centre,
  where QuantumLeap's flat 0.000009°/m would answer differently;
* a Room without any location, which no geo-query may return (not even
  ``disjoint``).

Each case asserts exactly which entity ids ``GET /v2/entities`` returns; the
exact-JSON cases check the other history endpoints and that stored values
come back raw (``"lat, lon"`` text stays text, GeoJSON stays GeoJSON).
Expected answers were derived by hand from the coordinates and checked
against an independent shapely/pyproj computation; coordinates are
``lat,lon`` in requests and in ``geo:*`` text, ``[lon, lat]`` in GeoJSON.
"""

from __future__ import annotations

import pytest
from pyproj import Geod

T0 = "2024-05-01T10:00:00.000Z"
IDX = "2024-05-01T10:00:00.000+00:00"


def _v2(eid: str, etype: str, location: dict | None, temperature: float) -> dict:
    entity = {
        "id": eid,
        "type": etype,
        "TimeInstant": {"type": "DateTime", "value": T0},
        "temperature": {"type": "Number", "value": temperature},
    }
    if location is not None:
        entity["location"] = location
    return {"subscriptionId": "geo-golden", "data": [entity]}


def _point(lon: float, lat: float) -> dict:
    return {"type": "geo:json", "value": {"type": "Point", "coordinates": [lon, lat]}}


def _text_point(text: str) -> dict:
    return {"type": "geo:point", "value": text}


CIBELES_GEOJSON = {"type": "Point", "coordinates": [-3.6932, 40.4193]}
CENTRO_RING = ["40.4140, -3.7080", "40.4140, -3.7000", "40.4190, -3.7000", "40.4190, -3.7080", "40.4140, -3.7080"]
RETIRO_PARK_BOX = ["40.4080, -3.6900", "40.4200, -3.6760"]
GRAN_VIA = ["40.4200, -3.7100", "40.4200, -3.6980"]
PLAZA_MAYOR = {
    "type": "Polygon",
    "coordinates": [
        [[-3.7078, 40.4150], [-3.7068, 40.4150], [-3.7068, 40.4160], [-3.7078, 40.4160], [-3.7078, 40.4150]]
    ],
}

# id -> (type, location attribute or None, temperature)
NGSIV2_ENTITIES = {
    # Madrid
    "sol": ("Sensor", _point(-3.7038, 40.4168), 21.0),
    "retiro": ("Sensor", _text_point("40.4153, -3.6845"), 19.0),
    "callao": ("Sensor", _text_point("40.4200, -3.7060"), 22.0),  # a vertex-free point on Gran Via
    "atocha": ("Sensor", _text_point("40.4066, -3.6892"), 23.0),
    "granvia": ("Street", {"type": "geo:line", "value": GRAN_VIA}, 24.0),
    "centro": ("Zone", {"type": "geo:polygon", "value": CENTRO_RING}, 25.0),
    "retiro-park": ("Zone", {"type": "geo:box", "value": RETIRO_PARK_BOX}, 18.0),
    "plaza-mayor": ("Zone", {"type": "geo:json", "value": PLAZA_MAYOR}, 26.0),
    # Barcelona, Plaça de Catalunya
    "bcn": ("Sensor", _point(2.1686, 41.3874), 27.0),
    # Helsinki: centre 60.1699 N, 24.9384 E. Geodesic (WGS84) / flat 0.000009°/m distances:
    "hel-centre": ("Sensor", _text_point("60.1699, 24.9384"), 5.0),  # 0 m
    "hel-east": ("Sensor", _point(24.9504, 60.1699), 6.0),  # 666 m / flat 1,333 m
    "hel-ne": ("Sensor", _text_point("60.1759, 24.9504"), 7.0),  # 944 m / flat 1,491 m
    "hel-north": ("Sensor", _point(24.9384, 60.1784), 8.0),  # 947 m / flat 944 m
    "hel-edge": ("Sensor", _text_point("60.17889, 24.9384"), 9.0),  # 1,002 m / flat 999 m
    "hel-far": ("Sensor", _point(24.9384, 60.1798), 10.0),  # 1,103 m / flat 1,100 m
    "hel-east-far": ("Sensor", _point(24.9569, 60.1699), 11.0),  # 1,027 m / flat 2,056 m
    # No location at all
    "kitchen": ("Room", None, 20.0),
}
LD_ID = "urn:ngsi-ld:Sensor:cibeles"  # NGSI-LD GeoProperty, Plaza de Cibeles
LD_NOTIFICATION = {
    "id": "urn:ngsi-ld:Notification:geo-golden",
    "type": "Notification",
    "notifiedAt": T0,
    "data": [
        {
            "id": LD_ID,
            "type": "Sensor",
            "location": {"type": "GeoProperty", "value": CIBELES_GEOJSON},
            "temperature": {"type": "Property", "value": 20.5, "observedAt": T0},
        }
    ],
}

CIBELES = LD_ID
LOCATED = frozenset({*(eid for eid, (_t, loc, _v) in NGSIV2_ENTITIES.items() if loc is not None), CIBELES})
HELSINKI = frozenset(eid for eid in LOCATED if eid.startswith("hel-"))

SOL = "40.4168,-3.7038"
PENTAGON = "40.410,-3.715;40.410,-3.695;40.425,-3.695;40.428,-3.705;40.425,-3.715;40.410,-3.715"
NS_LINE = "40.4100,-3.7050;40.4250,-3.7050"  # north-south across the centre and Gran Via
HEL = "60.1699,24.9384"
NORTH_OF_GRAN_VIA = "40.4218,-3.7020"  # 200 m north of Gran Via, 311 m from the centre polygon

# (case id, georel, geometry, coords, expected ids)
CASES = [
    # near: point only. Distances to stored lines/areas are to their nearest point.
    ("near-max-helsinki-60N", "near;maxDistance:1000", "point", HEL, {"hel-centre", "hel-east", "hel-ne", "hel-north"}),
    (
        "near-min-helsinki-60N",
        "near;minDistance:1000",
        "point",
        HEL,
        LOCATED - {"hel-centre", "hel-east", "hel-ne", "hel-north"},
    ),
    ("near-max-min", "near;maxDistance:1000;minDistance:900", "point", HEL, {"hel-ne", "hel-north"}),
    ("near-min-max", "near;minDistance:900;maxDistance:1000", "point", HEL, {"hel-ne", "hel-north"}),
    ("near-max-250-line", "near;maxDistance:250", "point", NORTH_OF_GRAN_VIA, {"granvia"}),
    ("near-max-350-line-polygon", "near;maxDistance:350", "point", NORTH_OF_GRAN_VIA, {"granvia", "centro"}),
    ("near-max-700", "near;maxDistance:700", "point", NORTH_OF_GRAN_VIA, {"granvia", "centro", "callao", "sol"}),
    (
        "near-min-max-ring-madrid",
        "near;minDistance:300;maxDistance:700",
        "point",
        NORTH_OF_GRAN_VIA,
        {"centro", "callao", "sol"},
    ),
    ("near-inside-box-is-distance-0", "near;maxDistance:1", "point", "40.4100,-3.6800", {"retiro-park"}),
    ("near-max-0-exact-point", "near;maxDistance:0", "point", "40.4153,-3.6845", {"retiro", "retiro-park"}),
    # coveredBy: the stored geometry lies inside the query geometry (boundary included)
    ("coveredBy-point", "coveredBy", "point", SOL, {"sol"}),
    ("coveredBy-line", "coveredBy", "line", "40.4200,-3.7150;40.4200,-3.6900", {"granvia", "callao"}),
    ("coveredBy-polygon", "coveredBy", "polygon", PENTAGON, {"sol", "callao", "granvia", "centro", "plaza-mayor"}),
    ("coveredBy-box", "coveredBy", "box", "40.405,-3.695;40.425,-3.670", {"retiro", "retiro-park", CIBELES, "atocha"}),
    (
        "coveredBy-box-60N",
        "coveredBy",
        "box",
        "60.16,24.92;60.1786,24.955",
        {"hel-centre", "hel-east", "hel-ne", "hel-north"},
    ),
    # intersects
    ("intersects-point", "intersects", "point", "40.4200,-3.7060", {"callao", "granvia"}),
    ("intersects-line", "intersects", "line", NS_LINE, {"granvia", "centro"}),
    (
        "intersects-polygon",
        "intersects",
        "polygon",
        "40.4150,-3.6950;40.4250,-3.6950;40.4250,-3.6800;40.4150,-3.6950",
        {CIBELES, "retiro-park"},
    ),
    ("intersects-box", "intersects", "box", "40.4150,-3.7010;40.4250,-3.6990", {"centro", "granvia"}),
    # equals: topological equality (any vertex order / orientation / corner order)
    ("equals-point", "equals", "point", "40.4153,-3.6845", {"retiro"}),
    ("equals-point-ld", "equals", "point", "40.4193,-3.6932", {CIBELES}),
    ("equals-line-reversed", "equals", "line", "40.4200,-3.6980;40.4200,-3.7100", {"granvia"}),
    (
        "equals-polygon-rotated-reversed",
        "equals",
        "polygon",
        "40.4190,-3.7000;40.4140,-3.7000;40.4140,-3.7080;40.4190,-3.7080;40.4190,-3.7000",
        {"centro"},
    ),
    (
        "equals-polygon-geojson",
        "equals",
        "polygon",
        "40.4150,-3.7078;40.4150,-3.7068;40.4160,-3.7068;40.4160,-3.7078;40.4150,-3.7078",
        {"plaza-mayor"},
    ),
    ("equals-box-swapped-corners", "equals", "box", "40.4200,-3.6760;40.4080,-3.6900", {"retiro-park"}),
    # disjoint: every located entity that does not intersect (never the Room without location)
    ("disjoint-point", "disjoint", "point", SOL, LOCATED - {"sol", "centro"}),
    ("disjoint-line", "disjoint", "line", NS_LINE, LOCATED - {"granvia", "centro"}),
    (
        "disjoint-polygon",
        "disjoint",
        "polygon",
        PENTAGON,
        LOCATED - {"sol", "callao", "granvia", "centro", "plaza-mayor"},
    ),
    ("disjoint-box-helsinki", "disjoint", "box", "60.16,24.92;60.19,24.97", LOCATED - HELSINKI),
]

# What NGSIv2 allows: near with point; the four others with every geometry.
ALLOWED = {("near", "point")} | {
    (rel, geom)
    for rel in ("coveredBy", "intersects", "equals", "disjoint")
    for geom in ("point", "line", "polygon", "box")
}


def geo(georel: str, geometry: str, coords: str) -> str:
    return f"georel={georel}&geometry={geometry}&coords={coords}"


@pytest.fixture(scope="module")
def geo_client(client_factory, store_url_factory, notify):
    with client_factory(store_url_factory("geo-golden")) as client:
        for eid, (etype, location, temperature) in NGSIV2_ENTITIES.items():
            notify(client, _v2(eid, etype, location, temperature))
        notify(client, LD_NOTIFICATION)
        yield client


def entity_ids(client, query: str) -> set[str]:
    response = client.get(f"/v2/entities?{query}")
    assert response.status_code == 200, response.text
    body = response.json()
    ids = [e["id"] for e in body]
    assert len(ids) == len(set(ids)), body
    return set(ids)


def test_dataset_without_geo_query(geo_client):
    assert entity_ids(geo_client, "") == LOCATED | {"kitchen"}


def test_cases_cover_every_allowed_combination():
    covered = {(georel.split(";")[0], geometry) for _id, georel, geometry, _c, _e in CASES}
    assert covered == ALLOWED
    modifiers = {georel for _id, georel, *_ in CASES if georel.startswith("near")}
    assert {
        "near;maxDistance:1000",
        "near;minDistance:1000",
        "near;maxDistance:1000;minDistance:900",
        "near;minDistance:900;maxDistance:1000",
    } <= modifiers


@pytest.mark.parametrize(
    ("georel", "geometry", "coords", "expected"), [pytest.param(*case[1:], id=case[0]) for case in CASES]
)
def test_georel_geometry(geo_client, georel, geometry, coords, expected):
    assert entity_ids(geo_client, geo(georel, geometry, coords)) == set(expected)


# --- far from the equator: geodesic, not flat degrees --------------------------------------------

FLAT_DEG_PER_M = 0.000009  # QuantumLeap's PostgreSQL path


def test_helsinki_distances_are_what_the_cases_assume():
    """The coordinates above are where we say they are (independent pyproj)."""
    wgs84 = Geod(ellps="WGS84")
    lat0, lon0 = 60.1699, 24.9384
    expected = {  # id: (lat, lon, geodesic m, flat m)
        "hel-east": (60.1699, 24.9504, 666, 1333),
        "hel-ne": (60.1759, 24.9504, 944, 1491),
        "hel-north": (60.1784, 24.9384, 947, 944),
        "hel-edge": (60.17889, 24.9384, 1002, 999),
        "hel-far": (60.1798, 24.9384, 1103, 1100),
        "hel-east-far": (60.1699, 24.9569, 1027, 2056),
    }
    for eid, (lat, lon, metres, flat) in expected.items():
        _, _, d = wgs84.inv(lon0, lat0, lon, lat)
        assert d == pytest.approx(metres, abs=1), eid
        flat_m = ((lat - lat0) ** 2 + (lon - lon0) ** 2) ** 0.5 / FLAT_DEG_PER_M
        assert flat_m == pytest.approx(flat, abs=1), eid


def test_60N_geodesic_answer_differs_from_flat_degrees(geo_client):
    """near;maxDistance:1000 at 60°N. The flat approximation would drop the
    points 0.012° east (666 m, "1,333 m") and north-east (944 m, "1,491 m")
    and keep the one 0.00899° north (1,002 m, "999 m"); geodesic does the
    opposite for all three."""
    got = entity_ids(geo_client, geo("near;maxDistance:1000", "point", HEL))
    assert {"hel-east", "hel-ne", "hel-north"} <= got
    assert not got & {"hel-edge", "hel-far", "hel-east-far"}
    flat_answer = {"hel-centre", "hel-north", "hel-edge"}
    assert got != flat_answer


# --- the other endpoints, exact JSON, raw values ----------------------------------------------------

NEAR_700 = geo("near;maxDistance:700", "point", NORTH_OF_GRAN_VIA)  # sol, callao, granvia, centro
BOX_EAST = geo("coveredBy", "box", "40.405,-3.695;40.425,-3.670")  # retiro, atocha, cibeles, retiro-park

GOLDEN = [
    (
        "entities",
        f"/v2/entities?{NEAR_700}",
        [
            {"id": "callao", "type": "Sensor", "index": IDX},  # the page listed by id
            {"id": "centro", "type": "Zone", "index": IDX},
            {"id": "granvia", "type": "Street", "index": IDX},
            {"id": "sol", "type": "Sensor", "index": IDX},
        ],
    ),
    (
        "entities-type",
        f"/v2/entities?type=Sensor&{NEAR_700}",
        [
            {"id": "callao", "type": "Sensor", "index": IDX},
            {"id": "sol", "type": "Sensor", "index": IDX},
        ],
    ),
    (
        "type-attr-location-raw",
        f"/v2/types/Sensor/attrs/location?{BOX_EAST}",
        {
            "type": "Sensor",
            "attrName": "location",
            "entities": [
                {"id": "atocha", "index": [IDX], "values": ["40.4066, -3.6892"]},
                {"id": "retiro", "index": [IDX], "values": ["40.4153, -3.6845"]},
                {"id": CIBELES, "index": [IDX], "values": [CIBELES_GEOJSON]},
            ],
        },
    ),
    (
        "type-attr-value",
        f"/v2/types/Sensor/attrs/temperature/value?{NEAR_700}",
        {
            "values": [
                {"id": "callao", "index": [IDX], "values": [22.0]},
                {"id": "sol", "index": [IDX], "values": [21.0]},
            ]
        },
    ),
    (
        "type-attr",
        f"/v2/types/Zone/attrs/location?{NEAR_700}",
        {
            "type": "Zone",
            "attrName": "location",
            "entities": [{"id": "centro", "index": [IDX], "values": [CENTRO_RING]}],
        },
    ),
    (
        "type",
        f"/v2/types/Zone?{BOX_EAST}&attrs=location,temperature",
        {
            "type": "Zone",
            "entities": [
                {
                    "id": "retiro-park",
                    "index": [IDX],
                    "attributes": [
                        {"attrName": "location", "values": [RETIRO_PARK_BOX]},
                        {"attrName": "temperature", "values": [18.0]},
                    ],
                }
            ],
        },
    ),
    (
        "type-value",
        f"/v2/types/Street/value?{NEAR_700}&attrs=location",
        {"values": [{"id": "granvia", "index": [IDX], "attributes": [{"attrName": "location", "values": [GRAN_VIA]}]}]},
    ),
    (
        "entity-match",
        f"/v2/entities/plaza-mayor?{geo('coveredBy', 'polygon', PENTAGON)}&attrs=location",
        {
            "id": "plaza-mayor",
            "type": "Zone",
            "index": [IDX],
            "attributes": [{"attrName": "location", "values": [PLAZA_MAYOR]}],
        },
    ),
    ("entity-no-match", f"/v2/entities/plaza-mayor?{NEAR_700}", []),
    (
        "entity-value",
        f"/v2/entities/sol/value?{NEAR_700}&attrs=temperature",
        {"index": [IDX], "attributes": [{"attrName": "temperature", "values": [21.0]}]},
    ),
    (
        "entity-attr-match",
        f"/v2/entities/hel-east/attrs/location?{geo('near;maxDistance:1000', 'point', HEL)}",
        {
            "id": "hel-east",
            "type": "Sensor",
            "attrName": "location",
            "index": [IDX],
            "values": [{"type": "Point", "coordinates": [24.9504, 60.1699]}],
        },
    ),
    ("entity-attr-no-match", f"/v2/entities/hel-edge/attrs/location?{geo('near;maxDistance:1000', 'point', HEL)}", []),
    (
        "entity-attr-value",
        f"/v2/entities/{CIBELES}/attrs/temperature/value?{BOX_EAST}",
        {"index": [IDX], "values": [20.5]},
    ),
    (
        "attrs-attr",
        f"/v2/attrs/temperature?{NEAR_700}",
        {
            "attrName": "temperature",
            "types": [
                {
                    "type": "Sensor",
                    "entities": [
                        {"id": "callao", "index": [IDX], "values": [22.0]},
                        {"id": "sol", "index": [IDX], "values": [21.0]},
                    ],
                },
                {"type": "Street", "entities": [{"id": "granvia", "index": [IDX], "values": [24.0]}]},
                {"type": "Zone", "entities": [{"id": "centro", "index": [IDX], "values": [25.0]}]},
            ],
        },
    ),
    (
        "attrs-attr-value",
        f"/v2/attrs/location/value?{geo('equals', 'box', '40.4200,-3.6760;40.4080,-3.6900')}",
        {
            "values": [
                {"type": "Zone", "entities": [{"id": "retiro-park", "index": [IDX], "values": [RETIRO_PARK_BOX]}]}
            ]
        },
    ),
    (
        "attrs",
        f"/v2/attrs?{geo('equals', 'line', '40.4200,-3.6980;40.4200,-3.7100')}&attrs=location",
        {
            "attrs": [
                {
                    "attrName": "location",
                    "types": [
                        {"type": "Street", "entities": [{"id": "granvia", "index": [IDX], "values": [GRAN_VIA]}]}
                    ],
                }
            ]
        },
    ),
    (
        "attrs-value",
        f"/v2/attrs/value?{geo('intersects', 'point', '40.4200,-3.7060')}&attrs=temperature",
        {
            "values": [
                {
                    "attrName": "temperature",
                    "types": [
                        {"type": "Sensor", "entities": [{"id": "callao", "index": [IDX], "values": [22.0]}]},
                        {"type": "Street", "entities": [{"id": "granvia", "index": [IDX], "values": [24.0]}]},
                    ],
                }
            ]
        },
    ),
    (
        "aggregation-global",
        f"/v2/types/Sensor/attrs/temperature?aggrMethod=avg&aggrScope=global&{NEAR_700}",
        {
            "type": "Sensor",
            "attrName": "temperature",
            "entities": [{"ids": ["callao", "sol"], "index": [], "values": [21.5]}],
        },
    ),
    (
        "aggregation-per-entity",
        f"/v2/attrs/temperature?aggrMethod=max&{BOX_EAST}",
        {
            "attrName": "temperature",
            "types": [
                {
                    "type": "Sensor",
                    "entities": [
                        {"id": "atocha", "index": [], "values": [23.0]},
                        {"id": "retiro", "index": [], "values": [19.0]},
                        {"id": CIBELES, "index": [], "values": [20.5]},
                    ],
                },
                {"type": "Zone", "entities": [{"id": "retiro-park", "index": [], "values": [18.0]}]},
            ],
        },
    ),
    ("no-location-never-matches", f"/v2/types/Room?{geo('disjoint', 'point', SOL)}", []),
]


@pytest.mark.parametrize(("path", "expected"), [pytest.param(p, e, id=name) for name, p, e in GOLDEN])
def test_endpoint_golden(geo_client, path, expected):
    response = geo_client.get(path)
    assert (response.status_code, response.json()) == (200, expected), response.text


# --- near to large lines and areas: edges run along parallels/meridians ----------------------------


LARGE_SHAPES = {
    "region": ("Area", {"type": "geo:box", "value": ["39, -4", "40, 2"]}),
    "parallel-road": ("Area", {"type": "geo:line", "value": ["40, -4", "40, 2"]}),
    "huge": ("Planet", {"type": "geo:box", "value": ["-80, -170", "80, 170"]}),
}


@pytest.fixture(scope="module")
def large_client(client_factory, store_url_factory, notify):
    with client_factory(store_url_factory("geo-large")) as client:
        for eid, (etype, location) in LARGE_SHAPES.items():
            notify(client, _v2(eid, etype, location, 1.0))
        yield client


@pytest.mark.parametrize(
    ("query", "expected"),
    [
        pytest.param("type=Area&" + geo("intersects", "point", "40.045,-1"), set(), id="5km-north-intersects"),
        pytest.param("type=Area&" + geo("near;maxDistance:1000", "point", "40.045,-1"), set(), id="5km-north-max1000"),
        pytest.param(
            "type=Area&" + geo("near;minDistance:4900;maxDistance:5100", "point", "40.045,-1"),
            {"region", "parallel-road"},
            id="5km-north-ring",
        ),
        pytest.param(
            "type=Area&" + geo("near;minDistance:1000", "point", "40.045,-1"),
            {"region", "parallel-road"},
            id="5km-north-min1000",
        ),
        pytest.param(
            "type=Area&" + geo("near;maxDistance:100", "point", "40.0001,-1"),
            {"region", "parallel-road"},
            id="11m-north-max100",
        ),
        pytest.param("type=Area&" + geo("near;minDistance:100", "point", "40.0001,-1"), set(), id="11m-north-min100"),
        pytest.param("type=Planet&" + geo("intersects", "point", "-17,180"), set(), id="antimeridian-intersects"),
        pytest.param(
            "type=Planet&" + geo("near;maxDistance:100000", "point", "-17,180"), set(), id="antimeridian-max100km"
        ),
    ],
)
def test_near_to_large_shapes(large_client, query, expected):
    """Distances to a line or area are to its edges as every other predicate
    sees them: straight in lon/lat (GeoJSON), so a geo:box edge is a parallel.

    A 6°-wide region box (39..40°N, 4°W..2°E) and a road along 40°N: a point
    0.045° north of 40°N (at 1°W) is 4,997 m from both; a point 0.0001° north
    is 11 m from both. A huge box (80°S..80°N, 170°W..170°E) is 1,064 km from
    17°S 180° (intersects agrees it is outside)."""
    assert entity_ids(large_client, query) == expected
