"""The NGSI-LD query language (clause 4.9) parses into a frozen AST and
evaluates terms against instance values."""

from __future__ import annotations

from datetime import UTC, datetime

import pytest

from tsdb_service.faces.ngsild import qlang
from tsdb_service.faces.ngsild.qlang import And, Not, Or, QueryError, Range, Term, parse


def test_comparison_and_logic_precedence():
    node = parse('speed>50;brandName=="Mercedes"|isParked')
    assert node == Or(
        (And((Term("speed", op=">", value=50), Term("brandName", op="==", value="Mercedes"))), Term("isParked"))
    )


def test_parentheses_group():
    node = parse("(a==1|b==2);c")
    assert node == And((Or((Term("a", op="==", value=1), Term("b", op="==", value=2))), Term("c")))


def test_sub_property_and_value_paths():
    assert parse("speed.accuracy<2") == Term("speed", ("accuracy",), op="<", value=2)
    assert parse('address[city]=="Madrid"') == Term("address", (), ("city",), "==", "Madrid")
    assert parse("address[geo.lat]>=40.5") == Term("address", (), ("geo", "lat"), ">=", 40.5)


def test_values():
    assert parse("a==1.5").value == 1.5
    assert parse("a==true").value is True
    assert parse("a==2018-08-01T12:05:00Z").value == datetime(2018, 8, 1, 12, 5, tzinfo=UTC)
    assert parse('a=="x,y"').value == "x,y"
    assert parse("a==1,2,3").value == (1, 2, 3)
    assert parse("a==10..20").value == Range(10, 20)
    assert parse("a==urn:ngsi-ld:Car:1").value == "urn:ngsi-ld:Car:1"


@pytest.mark.parametrize(
    "term,value,expected",
    [
        ("a>50", 60, True),
        ("a>50", 50, False),
        ("a>=50", 50, True),
        ("a<5", 4.5, True),
        ("a==1,2", 2, True),
        ("a!=1,2", 3, True),
        ("a==10..20", 15, True),
        ("a!=10..20", 15, False),
        ('a~="^Mer"', "Mercedes", True),
        ('a!~="^Mer"', "Mercedes", False),
        ("a==true", True, True),
        ("a==true", 1, False),
        ('a>"b"', "c", True),
        ("a>5", "text", False),
        ("a>2018-08-01T12:04:00Z", "2018-08-01T12:05:00Z", True),
        ("a==3", [1, 3], True),
        ("a!=3", [1, 3], False),  # != against an array: no element equal (clause 4.9)
        ("a!=4", [1, 3], True),
        ('a!~="^x"', ["xa", "b"], False),
        ("a", None, False),
    ],
)
def test_matches(term, value, expected):
    assert parse(term).matches(value) is expected


def test_evaluate_with_holds():
    node = parse("a;(b|c)")
    assert qlang.evaluate(node, lambda t: t.attr in {"a", "c"})
    assert not qlang.evaluate(node, lambda t: t.attr in {"b", "c"})


def test_map_attrs_expands_names():
    node = qlang.map_attrs(parse("speed>1|name"), lambda n: "https://x/" + n)
    assert {t.attr for t in qlang.terms(node)} == {"https://x/speed", "https://x/name"}


@pytest.mark.parametrize("bad", ["", "a==", "(a==1", 'a=="open', "a>1,2", "a~=[", "a>true", "==1", "a==1)"])
def test_invalid(bad):
    with pytest.raises(QueryError):
        parse(bad)


def test_negation_wildcards_and_bracket_paths():
    """Clause 4.9: !attr (existence negated), attr[*], attr[a][b]."""
    assert parse("!a;b==1") == And((Not(Term("a")), Term("b", op="==", value=1)))
    assert qlang.terms(parse("!a|b")) == [Term("a"), Term("b")]
    assert qlang.negates(parse("c;(!a|b)")) and not qlang.negates(parse("c;(a|b)"))
    assert not qlang.evaluate(parse("!a"), lambda t: True)
    assert parse('name[*]=="x"') == Term("name", (), ("*",), "==", "x")
    assert parse("a[b][c]>1") == parse("a[b.c]>1")


@pytest.mark.parametrize("bad", ["!a==1", "!", "owner{name}", 'owner{name}=="x"', "a[", "a[b"])
def test_refused(bad):
    with pytest.raises(QueryError):
        parse(bad)
