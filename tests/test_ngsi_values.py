"""NGSI types and values → storage kinds, including FIROS and ROS 2 payloads."""

from __future__ import annotations

import json
from datetime import UTC, datetime

import pytest

from tsdb_service.core.errors import ParseError
from tsdb_service.core.model import Kind
from tsdb_service.parse.values import attr_sample, decode_firos, to_json

EPOCH_2024_05_01_10 = datetime(2024, 5, 1, 10, tzinfo=UTC).timestamp()


def sample(ngsi_type, value, name="a", md=None):
    return attr_sample(name, ngsi_type, value, md)


# --- numbers -------------------------------------------------------------------


@pytest.mark.parametrize("ngsi_type", ["Number", "Float", "Double", "Decimal", "number", "FLOAT"])
def test_number_types(ngsi_type):
    s = sample(ngsi_type, 21.5)
    assert (s.kind, s.num, s.ngsi_type) == (Kind.NUMBER, 21.5, ngsi_type)


def test_number_with_json_int_stays_number():
    s = sample("Number", 21)
    assert (s.kind, s.num) == (Kind.NUMBER, 21.0)


def test_number_numeric_string_parsed():
    s = sample("Number", "21.5")
    assert (s.kind, s.num, s.txt) == (Kind.NUMBER, 21.5, None)


@pytest.mark.parametrize("value", ["n/a", "NaN", "inf", "1_000", "", "2024-05-01"])
def test_number_non_numeric_string_is_text(value):
    s = sample("Number", value)
    assert (s.kind, s.txt, s.ngsi_type) == (Kind.TEXT, value, "Number")


def test_number_huge_int_is_finite_float():
    s = sample("Number", 18446744073709551615)
    assert s.kind is Kind.NUMBER and s.num == float(18446744073709551615)


def test_number_with_bool_or_object_is_inferred():
    assert sample("Number", True).kind is Kind.BOOLEAN
    assert sample("Number", {"v": 1}).kind is Kind.STRUCTURED


@pytest.mark.parametrize("ngsi_type", ["Integer", "Int", "integer"])
def test_integer_types(ngsi_type):
    s = sample(ngsi_type, 7)
    assert (s.kind, s.num) == (Kind.INTEGER, 7.0)


def test_integer_variants():
    assert (sample("Integer", "42").kind, sample("Integer", "42").num) == (Kind.INTEGER, 42.0)
    assert sample("Integer", 7.0).kind is Kind.INTEGER
    assert (sample("Integer", 7.5).kind, sample("Integer", 7.5).num) == (Kind.NUMBER, 7.5)
    assert sample("Integer", "seven").kind is Kind.TEXT


# --- booleans, text, datetimes -----------------------------------------------------


@pytest.mark.parametrize(
    "value, num, js",
    [
        (True, 1.0, "true"),
        (False, 0.0, "false"),
        ("TRUE", 1.0, "true"),
        ("false", 0.0, "false"),
        (1, 1.0, "true"),
        (0, 0.0, "false"),
    ],
)
def test_boolean(value, num, js):
    s = sample("Boolean", value)
    assert (s.kind, s.num, s.js) == (Kind.BOOLEAN, num, js)


def test_boolean_mismatch_kept():
    assert sample("Boolean", "yes").kind is Kind.TEXT
    assert sample("Boolean", 2).kind is Kind.INTEGER


@pytest.mark.parametrize("ngsi_type", ["Text", "String", "URL", "text"])
def test_text_types(ngsi_type):
    s = sample(ngsi_type, "hello")
    assert (s.kind, s.txt) == (Kind.TEXT, "hello")


def test_text_type_with_date_string_stays_text():
    assert sample("Text", "2024-05-01T10:00:00Z").kind is Kind.TEXT


def test_text_type_with_number_is_inferred():
    assert sample("Text", 3.5).kind is Kind.NUMBER


@pytest.mark.parametrize("ngsi_type", ["DateTime", "ISO8601", "Date"])
def test_datetime_types_keep_original_text(ngsi_type):
    s = sample(ngsi_type, "2024-05-01T12:00:00+02:00")
    assert (s.kind, s.txt) == (Kind.DATETIME, "2024-05-01T12:00:00+02:00")
    assert s.num == EPOCH_2024_05_01_10


def test_datetime_unparseable_is_text():
    s = sample("DateTime", "yesterday")
    assert (s.kind, s.txt, s.num) == (Kind.TEXT, "yesterday", None)
    assert sample("DateTime", "5").kind is Kind.TEXT


def test_datetime_epoch_number():
    s = sample("DateTime", 1714557600)
    assert (s.kind, s.num, s.txt) == (Kind.DATETIME, EPOCH_2024_05_01_10, "2024-05-01T10:00:00Z")


# --- structured, relationship, null -------------------------------------------------


@pytest.mark.parametrize("ngsi_type", ["StructuredValue", "Object", "Array", "Json"])
def test_structured_types(ngsi_type):
    value = {"b": 1, "a": [1, 2, {"z": None}]}
    s = sample(ngsi_type, value)
    assert s.kind is Kind.STRUCTURED
    assert s.js == '{"b":1,"a":[1,2,{"z":null}]}'  # compact, key order kept


def test_structured_type_with_scalar_is_inferred():
    assert sample("StructuredValue", 3).kind is Kind.INTEGER


def test_relationship():
    s = sample("Relationship", "urn:ngsi-ld:Building:1")
    assert (s.kind, s.txt) == (Kind.RELATIONSHIP, "urn:ngsi-ld:Building:1")
    assert sample("Relationship", ["urn:a", "urn:b"]).kind is Kind.STRUCTURED


@pytest.mark.parametrize("ngsi_type", ["Number", "Text", "geo:point", None, "Whatever"])
def test_null_value(ngsi_type):
    s = sample(ngsi_type, None)
    assert s.kind is Kind.NULL
    assert s.ngsi_type == (ngsi_type or "None")


def test_metadata_passed_through():
    assert sample("Number", 1, md='{"unit":"C"}').md == '{"unit":"C"}'


# --- inference ----------------------------------------------------------------------


@pytest.mark.parametrize(
    "value, kind, ngsi_type",
    [
        (True, Kind.BOOLEAN, "Boolean"),
        (3, Kind.INTEGER, "Number"),
        (3.5, Kind.NUMBER, "Number"),
        ("hi", Kind.TEXT, "Text"),
        ("5", Kind.TEXT, "Text"),
        ("2024-05-01T10:00:00Z", Kind.DATETIME, "DateTime"),
        ("2024-05-01", Kind.DATETIME, "DateTime"),
        ({"a": 1}, Kind.STRUCTURED, "StructuredValue"),
        ([1, "x"], Kind.STRUCTURED, "StructuredValue"),
        ({"type": "Point", "coordinates": [1, 2]}, Kind.STRUCTURED, "StructuredValue"),
    ],
)
def test_inference_without_type(value, kind, ngsi_type):
    s = sample(None, value)
    assert (s.kind, s.ngsi_type) == (kind, ngsi_type)


def test_inference_keeps_unknown_declared_type():
    s = sample("Temperature", 21)
    assert (s.kind, s.ngsi_type) == (Kind.INTEGER, "Temperature")


def test_inferred_datetime_num():
    assert sample(None, "2024-05-01T10:00:00Z").num == EPOCH_2024_05_01_10


def test_location_name_with_geojson_is_geo_whatever_the_type():
    point = {"type": "Point", "coordinates": [2.1493, 41.3763]}
    for ngsi_type in (None, "StructuredValue", "Property"):
        s = sample(ngsi_type, point, name="location")
        assert s.kind is Kind.GEO
        assert (s.geo.lon, s.geo.lat) == (2.1493, 41.3763)
    assert sample(None, point, name="location").ngsi_type == "geo:json"


def test_location_name_with_invalid_geojson_is_structured():
    s = sample(None, {"type": "Point", "coordinates": [500, 0]}, name="location")
    assert s.kind is Kind.STRUCTURED


def test_location_name_is_case_sensitive():
    assert sample(None, {"type": "Point", "coordinates": [1, 2]}, name="Location").kind is Kind.STRUCTURED


# --- geo types -----------------------------------------------------------------------


def test_geo_point_sample_keeps_raw_value():
    s = sample("geo:point", "41.3763, 2.1493", name="position")
    assert s.kind is Kind.GEO
    assert s.js == '"41.3763, 2.1493"'
    assert json.loads(s.geo.geojson)["coordinates"] == [2.1493, 41.3763]


def test_geo_json_sample_keeps_raw_value():
    raw = {"type": "Point", "coordinates": [2, 41], "crs": "x"}
    s = sample("geo:json", raw)
    assert s.js == '{"type":"Point","coordinates":[2,41],"crs":"x"}'
    assert json.loads(s.geo.geojson) == {"type": "Point", "coordinates": [2.0, 41.0]}


@pytest.mark.parametrize("ngsi_type", ["geo:line", "geo:box", "geo:polygon", "GeoProperty"])
def test_other_geo_types(ngsi_type):
    values = {
        "geo:line": ["40, -3", "41, -2"],
        "geo:box": ["40, -3", "41, -2"],
        "geo:polygon": ["40, -3", "41, -3", "41, -2", "40, -3"],
        "GeoProperty": {"type": "Point", "coordinates": [-3, 40]},
    }
    s = sample(ngsi_type, values[ngsi_type])
    assert s.kind is Kind.GEO
    assert -3 <= s.geo.lon <= -2 and 40 <= s.geo.lat <= 41


def test_invalid_geo_kept_as_text_or_structured():
    s = sample("geo:point", "91, 0")
    assert (s.kind, s.txt, s.ngsi_type) == (Kind.TEXT, "91, 0", "geo:point")
    s = sample("geo:polygon", ["0, 0", "0, 1", "1, 1"])
    assert (s.kind, s.js) == (Kind.STRUCTURED, '["0, 0","0, 1","1, 1"]')
    s = sample("geo:json", {"type": "Point", "coordinates": "x"})
    assert s.kind is Kind.STRUCTURED
    assert sample("geo:point", 5).kind is Kind.INTEGER


# --- ROS -------------------------------------------------------------------------------

FIROS_STRING = "{%27firosstamp%27: 1505398290.89, %27data%27: %27hello world%27}"
FIROS_ODOMETRY = (
    "{%27header%27: {%27stamp%27: {%27secs%27: 1505398290, %27nsecs%27: 12}, %27frame_id%27: %27odom%27, "
    "%27seq%27: 7}, %27child_frame_id%27: %27base_link%27, %27pose%27: {%27pose%27: {%27position%27: "
    "{%27x%27: 1.5, %27y%27: -0.25, %27z%27: 0.0}, %27orientation%27: {%27x%27: 0.0, %27y%27: 0.0, "
    "%27z%27: 0.7071, %27w%27: 0.7071}}, %27covariance%27: (0.1, 0.0, 0.0, 0.0, 0.0, 0.2)}, "
    "%27twist%27: {%27twist%27: {%27linear%27: {%27x%27: 0.5, %27y%27: 0.0, %27z%27: 0.0}, "
    "%27angular%27: {%27x%27: 0.0, %27y%27: 0.0, %27z%27: 0.1}}, %27covariance%27: ()}, "
    "%27firosstamp%27: 1505398290.89, %27valid%27: True, %27note%27: None}"
)


def test_firos_string_message():
    s = sample("std_msgs.msg.String", FIROS_STRING, name="chatter")
    assert (s.kind, s.ngsi_type) == (Kind.STRUCTURED, "std_msgs.msg.String")
    assert json.loads(s.js) == {"firosstamp": 1505398290.89, "data": "hello world"}


def test_firos_odometry_message():
    s = sample("nav_msgs.msg.Odometry", FIROS_ODOMETRY, name="odom")
    assert (s.kind, s.ngsi_type) == (Kind.STRUCTURED, "nav_msgs.msg.Odometry")
    doc = json.loads(s.js)
    assert doc["pose"]["pose"]["position"] == {"x": 1.5, "y": -0.25, "z": 0.0}
    assert doc["pose"]["covariance"] == [0.1, 0.0, 0.0, 0.0, 0.0, 0.2]  # tuple → list
    assert doc["twist"]["covariance"] == []
    assert doc["header"]["frame_id"] == "odom"
    assert (doc["valid"], doc["note"]) == (True, None)


def test_firos_ros2_spelling():
    assert sample("std_msgs/msg/String", FIROS_STRING).kind is Kind.STRUCTURED


def test_firos_undecodable_is_text():
    for value in ["not a literal", "[1, 2]", "__import__(%27os%27)", "{%27a%27: 1", "{[]: 1}"]:
        s = sample("std_msgs.msg.String", value)
        assert (s.kind, s.txt) == (Kind.TEXT, value)


def test_firos_python_only_values_become_json():
    assert decode_firos("{%27b%27: b%27hi%27, %27n%27: 1e999, %27s%27: {1}, 3: %27x%27}") == {
        "b": "hi",
        "n": None,
        "s": [1],
        "3": "x",
    }


def test_firos_dict_value_is_structured():
    s = sample("std_msgs.msg.Int32", {"data": 3})
    assert (s.kind, s.js) == (Kind.STRUCTURED, '{"data":3}')


def test_ros2_object_payloads():
    s = sample("Object", {"data": 3}, name="counter")
    assert (s.kind, s.js, s.ngsi_type) == (Kind.STRUCTURED, '{"data":3}', "Object")
    odom = {
        "header": {"stamp": {"sec": 1, "nanosec": 2}, "frame_id": "odom"},
        "pose": {"pose": {"position": {"x": 1.0, "y": 2.0, "z": 0.0}}, "covariance": [0.0] * 36},
    }
    s = sample("Object", odom, name="odom")
    assert s.kind is Kind.STRUCTURED
    assert json.loads(s.js) == odom


# --- JSON text -------------------------------------------------------------------------


def test_to_json_within_the_nesting_limit():
    value = 1
    for _ in range(100):
        value = [value]
    assert to_json(value) == "[" * 100 + "1" + "]" * 100


def test_to_json_too_deep_is_parse_error():
    value = 1
    for _ in range(5000):
        value = [value]
    with pytest.raises(ParseError):
        to_json(value)


def test_names_kept_exactly():
    for name in ["Temp'; DROP TABLE x;--", 'quo"te', "ünïcødé_温度", "x" * 10_000, "CamelCase"]:
        assert sample("Number", 1, name=name).name == name
