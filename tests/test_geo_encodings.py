"""Every NGSI location encoding normalises to lon/lat GeoJSON with bounds."""

from __future__ import annotations

import json

import pytest

from tsdb_service.geo.encodings import from_geojson, from_ngsi, looks_like_geojson, parse_lat_lon


def coords(geometry):
    return json.loads(geometry.geojson)["coordinates"]


@pytest.mark.parametrize("text", ["41.3763, 2.1493", "41.3763,2.1493", " 41.3763 ,  2.1493 "])
def test_geo_point_text_is_lat_lon(text):
    g = from_ngsi("geo:point", text)
    assert json.loads(g.geojson) == {"type": "Point", "coordinates": [2.1493, 41.3763]}
    assert (g.lon, g.lat) == (2.1493, 41.3763)
    assert (g.min_lon, g.min_lat, g.max_lon, g.max_lat) == (2.1493, 41.3763, 2.1493, 41.3763)


@pytest.mark.parametrize(
    "text",
    ["91, 0", "-90.5, 0", "0, 180.1", "0, -181", "abc, 1", "1", "1, 2, 3", "nan, 1", "1, inf", "1_0, 2", "", 5, None],
)
def test_geo_point_invalid(text):
    assert from_ngsi("geo:point", text) is None


def test_geo_point_range_edges_are_valid():
    g = from_ngsi("geo:point", "-90, 180")
    assert (g.lon, g.lat) == (180.0, -90.0)


def test_geo_line_swaps_to_lon_lat_and_uses_centroid():
    g = from_ngsi("geo:line", ["40.0, -3.0", "42.0, -1.0"])
    assert json.loads(g.geojson)["type"] == "LineString"
    assert coords(g) == [[-3.0, 40.0], [-1.0, 42.0]]
    assert (g.lon, g.lat) == pytest.approx((-2.0, 41.0))
    assert (g.min_lon, g.min_lat, g.max_lon, g.max_lat) == (-3.0, 40.0, -1.0, 42.0)


def test_geo_line_needs_two_points():
    assert from_ngsi("geo:line", ["40.0, -3.0"]) is None
    assert from_ngsi("geo:line", "40.0, -3.0") is None


@pytest.mark.parametrize("corners", [["40, -4", "42, -2"], ["42, -2", "40, -4"]])
def test_geo_box_becomes_polygon(corners):
    g = from_ngsi("geo:box", corners)
    doc = json.loads(g.geojson)
    assert doc["type"] == "Polygon"
    assert doc["coordinates"] == [[[-4.0, 40.0], [-2.0, 40.0], [-2.0, 42.0], [-4.0, 42.0], [-4.0, 40.0]]]
    assert (g.lon, g.lat) == pytest.approx((-3.0, 41.0))
    assert (g.min_lon, g.min_lat, g.max_lon, g.max_lat) == (-4.0, 40.0, -2.0, 42.0)


@pytest.mark.parametrize("corners", [["40, -4"], ["40, -4", "42, -2", "43, 1"], ["40, -4", "40, -2"], ["x", "1, 2"]])
def test_geo_box_invalid(corners):
    assert from_ngsi("geo:box", corners) is None


def test_geo_polygon_closed_ring():
    ring = ["0, 0", "0, 2", "2, 2", "2, 0", "0, 0"]
    g = from_ngsi("geo:polygon", ring)
    assert coords(g) == [[[0.0, 0.0], [2.0, 0.0], [2.0, 2.0], [0.0, 2.0], [0.0, 0.0]]]
    assert (g.lon, g.lat) == pytest.approx((1.0, 1.0))


def test_geo_polygon_lat_lon_order():
    g = from_ngsi("geo:polygon", ["10, 20", "10, 21", "11, 21", "10, 20"])
    assert coords(g)[0][0] == [20.0, 10.0]
    assert (g.min_lon, g.min_lat, g.max_lon, g.max_lat) == (20.0, 10.0, 21.0, 11.0)


@pytest.mark.parametrize(
    "ring",
    [["0, 0", "0, 2", "2, 2", "2, 0"], ["0, 0", "0, 2", "0, 0"], ["0, 0", "0, 2", "2, 2", "95, 0", "0, 0"], "0, 0"],
)
def test_geo_polygon_invalid(ring):
    assert from_ngsi("geo:polygon", ring) is None


def test_geojson_point_keeps_lon_lat():
    g = from_ngsi("geo:json", {"type": "Point", "coordinates": [2.1493, 41.3763]})
    assert coords(g) == [2.1493, 41.3763]
    assert (g.lon, g.lat) == (2.1493, 41.3763)


def test_geojson_normalised_drops_foreign_members_and_floats_ints():
    g = from_geojson({"type": "Point", "coordinates": [2, 41], "crs": {"x": 1}, "bbox": [1, 2, 3, 4]})
    assert json.loads(g.geojson) == {"type": "Point", "coordinates": [2.0, 41.0]}


def test_geojson_altitude_kept():
    g = from_geojson({"type": "Point", "coordinates": [2.0, 41.0, 120.5]})
    assert coords(g) == [2.0, 41.0, 120.5]


@pytest.mark.parametrize(
    "value, centre, bounds",
    [
        ({"type": "MultiPoint", "coordinates": [[0, 0], [2, 2]]}, (1, 1), (0, 0, 2, 2)),
        ({"type": "LineString", "coordinates": [[0, 0], [4, 0]]}, (2, 0), (0, 0, 4, 0)),
        ({"type": "MultiLineString", "coordinates": [[[0, 0], [0, 2]], [[2, 0], [2, 2]]]}, (1, 1), (0, 0, 2, 2)),
        ({"type": "Polygon", "coordinates": [[[0, 0], [4, 0], [4, 2], [0, 2], [0, 0]]]}, (2, 1), (0, 0, 4, 2)),
        (
            {
                "type": "MultiPolygon",
                "coordinates": [[[[0, 0], [1, 0], [1, 1], [0, 1], [0, 0]]], [[[2, 0], [3, 0], [3, 1], [2, 1], [2, 0]]]],
            },
            (1.5, 0.5),
            (0, 0, 3, 1),
        ),
        (
            {
                "type": "GeometryCollection",
                "geometries": [
                    {"type": "Point", "coordinates": [5, 5]},
                    {"type": "Polygon", "coordinates": [[[0, 0], [2, 0], [2, 2], [0, 2], [0, 0]]]},
                ],
            },
            (1, 1),
            (0, 0, 5, 5),
        ),
    ],
)
def test_geojson_shapes(value, centre, bounds):
    g = from_geojson(value)
    assert (g.lon, g.lat) == pytest.approx(centre)
    assert (g.min_lon, g.min_lat, g.max_lon, g.max_lat) == pytest.approx(bounds)
    assert json.loads(g.geojson)["type"] == value["type"]


def test_geojson_feature_and_collection_unwrap_to_geometry():
    point = {"type": "Point", "coordinates": [1, 2]}
    g = from_geojson({"type": "Feature", "geometry": point, "properties": {"a": 1}})
    assert json.loads(g.geojson) == {"type": "Point", "coordinates": [1.0, 2.0]}
    g = from_geojson({"type": "FeatureCollection", "features": [{"type": "Feature", "geometry": point}]})
    assert json.loads(g.geojson)["type"] == "GeometryCollection"


def test_geojson_text_under_geo_json():
    g = from_ngsi("geo:json", '{"type": "Point", "coordinates": [1, 2]}')
    assert (g.lon, g.lat) == (1.0, 2.0)
    assert from_ngsi("geo:json", "not json") is None


def test_dict_under_simple_type_is_read_as_geojson():
    g = from_ngsi("geo:point", {"type": "Point", "coordinates": [1, 2]})
    assert (g.lon, g.lat) == (1.0, 2.0)


@pytest.mark.parametrize(
    "value",
    [
        {"type": "Point", "coordinates": [200, 0]},
        {"type": "Point", "coordinates": [0, 91]},
        {"type": "Point", "coordinates": [0]},
        {"type": "Point", "coordinates": [0, 1, 2, 3]},
        {"type": "Point", "coordinates": ["1", "2"]},
        {"type": "Point", "coordinates": [True, 2]},
        {"type": "Point", "coordinates": None},
        {"type": "Point"},
        {"type": "LineString", "coordinates": [[0, 0]]},
        {"type": "Polygon", "coordinates": [[[0, 0], [1, 0], [1, 1], [0, 0.5]]]},
        {"type": "Polygon", "coordinates": []},
        {"type": "MultiPolygon", "coordinates": [[]]},
        {"type": "GeometryCollection", "geometries": []},
        {"type": "GeometryCollection", "geometries": [{"type": "Point", "coordinates": [0, 99]}]},
        {"type": "Feature", "geometry": None},
        {"type": "FeatureCollection", "features": "x"},
        {"type": "Circle", "coordinates": [0, 0]},
        {"type": ["Point"], "coordinates": [0, 0]},
        {"coordinates": [0, 0]},
        [0, 0],
        "Point",
        None,
    ],
)
def test_geojson_invalid(value):
    assert from_geojson(value) is None


def test_deeply_nested_collections_are_refused_not_recursed():
    value = {"type": "Point", "coordinates": [0, 0]}
    for _ in range(50):
        value = {"type": "GeometryCollection", "geometries": [value]}
    assert from_geojson(value) is None


def test_looks_like_geojson():
    assert looks_like_geojson({"type": "Point", "coordinates": [0, 0]})
    assert looks_like_geojson({"type": "Feature"})
    assert not looks_like_geojson({"type": "Room"})
    assert not looks_like_geojson({"type": ["Point"]})
    assert not looks_like_geojson("Point")


def test_parse_lat_lon():
    assert parse_lat_lon("41.3763, 2.1493") == [2.1493, 41.3763]
    assert parse_lat_lon("41.3763,2.1493") == [2.1493, 41.3763]
    assert parse_lat_lon([41, 2]) is None
