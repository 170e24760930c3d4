"""The array form of the exact geo predicate (``relations_hold``) answers as
the one-geometry form (``relation_holds``) for every relation of both APIs:
the NGSI-LD geo-query tests thousands of window positions with it at once."""

from __future__ import annotations

import random

import orjson
import pytest
from shapely.geometry import LineString, Point, Polygon, mapping

from tsdb_service.faces.ngsild.geoquery import GEORELS as LD_GEORELS
from tsdb_service.faces.ngsild.geoquery import parse_ld_geo
from tsdb_service.geo.filter import geometries, relation_holds, relations_hold

CENTRE = (-3.7038, 40.4168)
AREA = [[-3.73, 40.40], [-3.68, 40.40], [-3.68, 40.44], [-3.73, 40.44], [-3.73, 40.40]]
QUERY_AREA = Polygon(AREA)


def _stored(rng: random.Random) -> list[str]:
    """Points, lines and polygons scattered ~5 km around the centre, as stored."""
    out = []
    for _ in range(300):
        lon = CENTRE[0] + rng.uniform(-0.06, 0.06)
        lat = CENTRE[1] + rng.uniform(-0.05, 0.05)
        d = rng.uniform(0.001, 0.02)
        geom = rng.choice(
            [
                Point(lon, lat),
                LineString([(lon, lat), (lon + d, lat + d)]),
                Polygon([(lon, lat), (lon + d, lat), (lon + d, lat + d), (lon, lat + d)]),
            ]
        )
        out.append(orjson.dumps(mapping(geom)).decode())
    around = Polygon([(-3.71, 40.41), (-3.70, 40.41), (-3.70, 40.42), (-3.71, 40.42)])  # covers the centre
    out += [orjson.dumps(mapping(g)).decode() for g in (around, QUERY_AREA)]
    out += ['{"type":"Point","coordinates":[]}', "not json", '{"type":"Polygon","coordinates":[]}']
    return out


QUERIES = [
    ("near;maxDistance==2500", "Point", [*CENTRE]),
    ("near;minDistance==2500", "Point", [*CENTRE]),
    ("near;minDistance==1000;maxDistance==3000", "Point", [*CENTRE]),
    *[(rel, "Polygon", [AREA]) for rel in LD_GEORELS if rel != "near"],
    ("contains", "Point", [*CENTRE]),
    ("intersects", "LineString", [[-3.75, 40.39], [-3.66, 40.45]]),
]


@pytest.mark.parametrize(("georel", "geometry", "coordinates"), QUERIES)
def test_the_array_form_answers_as_one_at_a_time(georel, geometry, coordinates):
    stored = _stored(random.Random(georel + geometry))
    geo = parse_ld_geo(georel, geometry, orjson.dumps(coordinates).decode())
    one_by_one = [relation_holds(geo.georel, geo.shape, text, geo.max_distance, geo.min_distance) for text in stored]
    assert list(geo.matching(stored)) == one_by_one
    assert any(one_by_one) and not all(one_by_one)


def test_the_ngsiv2_names_answer_as_one_at_a_time():
    stored = _stored(random.Random(2))
    shape = QUERY_AREA
    for georel in ("coveredBy", "intersects", "disjoint", "equals"):
        expected = [relation_holds(georel, shape, text) for text in stored]
        assert list(relations_hold(georel, shape, geometries(stored))) == expected, georel


def test_nothing_to_test_is_an_empty_answer():
    geo = parse_ld_geo("near;maxDistance==10", "Point", "[0, 0]")
    assert geo.matching([]).tolist() == []
