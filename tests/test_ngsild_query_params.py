"""Query parameters → a frozen TemporalQuery: every parameter and every
refusal, without a database."""

from __future__ import annotations

from datetime import UTC, datetime

import pytest

from tsdb_service.core.errors import BadRequestData, InvalidRequest, TooManyResults
from tsdb_service.faces.ngsild.context import DEFAULT_VOCAB, ContextStore
from tsdb_service.faces.ngsild.params import parse_duration, parse_types, query_from_body, query_from_params
from tsdb_service.faces.ngsild.query import Duration, Format, TimeProperty, TypeAnd, TypeName, TypeOr

TERMS = ContextStore().term_map(None)
V = DEFAULT_VOCAB


def q(**params):
    return query_from_params({k: str(v) for k, v in params.items()}, "t", TERMS, limits=(100, 1000))


def test_timerel_windows_are_half_open():
    at = datetime(2018, 8, 1, 12, tzinfo=UTC)
    end = datetime(2018, 8, 1, 13, tzinfo=UTC)
    w = q(type="Vehicle", timerel="before", timeAt="2018-08-01T12:00:00Z").window
    assert (w.start, w.end) == (None, at)
    w = q(type="Vehicle", timerel="after", timeAt="2018-08-01T12:00:00Z").window
    assert (w.start, w.end) == (at, None)
    w = q(type="Vehicle", timerel="between", timeAt="2018-08-01T12:00:00Z", endTimeAt="2018-08-01T13:00:00Z").window
    assert (w.start, w.end, w.timeproperty) == (at, end, TimeProperty.OBSERVED_AT)
    w = q(type="Vehicle", timerel="after", timeAt="2018-08-01T14:00:00+02:00", timeproperty="modifiedAt").window
    assert (w.start, w.timeproperty) == (at, TimeProperty.MODIFIED_AT)


@pytest.mark.parametrize(
    "params",
    [
        {"type": "V", "timerel": "during", "timeAt": "2018-08-01T12:00:00Z"},
        {"type": "V", "timerel": "before"},
        {"type": "V", "timerel": "between", "timeAt": "2018-08-01T12:00:00Z"},
        {"type": "V", "timerel": "between", "timeAt": "2018-08-01T12:00:00Z", "endTimeAt": "2018-08-01T11:00:00Z"},
        {"type": "V", "timeAt": "2018-08-01T12:00:00Z"},
        {"type": "V", "timerel": "after", "timeAt": "yesterday"},
        {"type": "V", "timeproperty": "updatedAt"},
        {"type": "V", "lastN": "0"},
        {"type": "V", "lastN": "-1"},
        {"type": "V", "limit": "x"},
        {"type": "V", "format": "aggregatedValues"},
        {"type": "V", "timerel": "after", "timeAt": "2018-08-01"},
        {"type": "V", "attrs": "speed", "pick": "id"},
        {"type": "V", "attrs": "speed", "omit": "name"},
        {"type": "V", "pick": "id,speed", "omit": "speed"},
        {"type": "V", "orderBy": "id;up"},
        {"type": "V", "orderBy": "id,name"},
        {"type": "V", "q": "speed>"},
        {"type": "(V"},
        {"type": "V;;W"},
        {"type": "V", "idPattern": "("},
        {"type": "V", "georel": "near;maxDistance==10"},
        {"type": "V", "georel": "near", "geometry": "Point", "coordinates": "[1,2]"},
        {"type": "V", "georel": "within", "geometry": "Circle", "coordinates": "[1,2]"},
        {"type": "V", "georel": "within", "geometry": "Polygon", "coordinates": "[[1,2]]"},
        {"type": "V", "georel": "near;maxDistance==10", "geometry": "Point", "coordinates": "[200,2]"},
        {"type": "V", "orderBy": "speed"},
        {"type": "V", "local": "yes"},
        {"type": "V", "limit": "0"},
        {},
        {"id": "urn:a"},
        {"timerel": "after", "timeAt": "2018-08-01T12:00:00Z"},
    ],
)
def test_bad_requests(params):
    with pytest.raises(BadRequestData):
        q(**params)


@pytest.mark.parametrize("params", [{"options": "fancy"}, {"format": "keyValues"}, {"options": "temporalValues,x"}])
def test_unknown_representations_are_invalid_requests(params):
    """Clause 6.3.6: a parameter value outside its grammar is an InvalidRequest."""
    with pytest.raises(InvalidRequest):
        q(type="V", **params)


def test_aggregation_parameters_wait_for_aggregation():
    """``format`` wins over ``options``; aggrMethods without aggregation are
    checked, not used (the ETSI suite's 021_19_02)."""
    query = q(type="V", options="aggregatedValues", format="temporalValues", aggrMethods="sum")
    assert query.format is Format.TEMPORAL_VALUES and query.aggregation is None


def test_order_by_id_either_way():
    assert q(type="V", orderBy="id").descending is False
    assert q(type="V", orderBy="id;asc").descending is False
    assert q(type="V", orderBy="id;desc").descending is True


@pytest.mark.parametrize(
    "params",
    [
        {"type": "V", "format": "aggregatedValues", "aggrMethods": "median"},
        {"type": "V", "aggrMethods": "median"},
        {"type": "V", "aggrPeriodDuration": "1 hour"},
    ],
)
def test_aggregation_parameters_outside_their_grammar_are_invalid_requests(params):
    """An unknown aggrMethods value or a duration that is none: a query
    parameter outside its grammar, InvalidRequest as for format and options
    (clauses 6.19, 6.20 with 4.5.19)."""
    with pytest.raises(InvalidRequest):
        q(**params)


def test_limits_and_csf():
    with pytest.raises(TooManyResults):
        q(type="V", limit=1001)
    assert q(type="V", scopeQ="/Madrid/#").scope_q is not None
    q(type="V", csf="x")  # a valid csf selects no registration here: the local history answers
    with pytest.raises(BadRequestData):
        q(type="V", csf="x==")
    assert q(type="V", offsetN="5").offset_n == 5
    assert q(type="V", options="concise").format is q(type="V", format="concise").format is Format.CONCISE


def test_lang_ranges_best_first():
    assert q(type="V", lang="fr").lang == (("fr", 1.0),)
    assert q(type="V", lang="en-GB;q=0.5, NL, *;q=0.1, de;q=0").lang == (("nl", 1.0), ("en-gb", 0.5), ("*", 0.1))
    for bad in ("", "fr;q=2", "*x", "en_GB", "fr;quality=1"):
        if bad:
            with pytest.raises(BadRequestData):
                q(type="V", lang=bad)


def test_one_of_the_required_filters_is_enough():
    assert q(attrs="speed").attrs == (V + "speed",)
    assert q(q="speed>1").q is not None
    assert q(georel="near;maxDistance==10", geometry="Point", coordinates="[1,2]").geo is not None
    assert q(local="true").local


def test_type_expressions():
    assert parse_types("Vehicle", TERMS) == TypeName(V + "Vehicle", "Vehicle")
    assert parse_types("A,B", TERMS) == TypeOr((TypeName(V + "A", "A"), TypeName(V + "B", "B")))
    assert parse_types("A;B|C", TERMS) == TypeOr(
        (TypeAnd((TypeName(V + "A", "A"), TypeName(V + "B", "B"))), TypeName(V + "C", "C"))
    )
    assert parse_types("(A|B);C", TERMS) == TypeAnd(
        (TypeOr((TypeName(V + "A", "A"), TypeName(V + "B", "B"))), TypeName(V + "C", "C"))
    )
    assert parse_types("https://example.org/T", TERMS) == TypeName("https://example.org/T", "https://example.org/T")


def test_representation_format_wins_over_options():
    assert q(type="V").format is Format.NORMALIZED
    assert q(type="V", options="temporalValues").format is Format.TEMPORAL_VALUES
    assert q(type="V", format="temporalValues", options="sysAttrs").sys_attrs
    both = q(type="V", options="temporalValues,aggregatedValues", aggrMethods="sum,max")
    assert both.format is Format.AGGREGATED and both.aggregation.methods == ("sum", "max")
    assert both.aggregation.period == Duration()
    assert q(type="V", format="normalized", options="temporalValues").format is Format.NORMALIZED


@pytest.mark.parametrize(
    "text,duration",
    [
        ("PT0S", Duration()),
        ("P0D", Duration()),
        ("PT1H", Duration(micros=3_600_000_000)),
        ("P1W", Duration(days=7)),
        ("P1Y2M", Duration(months=14)),
        ("P1DT0.5S", Duration(days=1, micros=500_000)),
        ("P3Y6M4DT12H30M5S", Duration(42, 4, (12 * 3600 + 30 * 60 + 5) * 1_000_000)),
    ],
)
def test_durations(text, duration):
    assert parse_duration(text) == duration


@pytest.mark.parametrize("bad", ["P", "PT", "1H", "P1H", "PT1D", "P1DT", "-P1D", "P1.5D"])
def test_bad_durations(bad):
    with pytest.raises(BadRequestData):
        parse_duration(bad)


def test_pick_omit_attrs_dataset_paging():
    assert q(type="V", attrs="speed,name").wanted_attrs == (V + "speed", V + "name")
    query = q(
        type="V",
        pick="id,speed",
        omit="name",
        datasetId="urn:ds:1,@none",
        limit=5,
        offset=10,
        count="true",
        lastN=3,
        orderBy="id",
    )
    assert query.pick == ("id", V + "speed") and query.omit == (V + "name",)
    assert query.wanted_attrs == (V + "speed",)
    assert query.dataset_ids == ("urn:ds:1", "@none")
    assert (query.limit, query.offset, query.count, query.last_n) == (5, 10, True, 3)


def test_post_query_body():
    body = {
        "type": "Query",
        "entities": [{"type": "Vehicle"}, {"id": "urn:x", "type": "Car"}],
        "attrs": ["speed"],
        "q": "speed>50",
        "geoQ": {
            "georel": "near;maxDistance==2000",
            "geometry": "Point",
            "coordinates": [-3.7, 40.4],
            "geoproperty": "location",
        },
        "temporalQ": {"timerel": "after", "timeAt": "2018-08-01T12:00:00Z", "lastN": 2},
    }
    query = query_from_body(body, {"options": "temporalValues"}, "t", TERMS, limits=(100, 1000))
    assert len(query.selectors) == 2 and query.selectors[1].ids == ("urn:x",)
    assert query.last_n == 2 and query.format is Format.TEMPORAL_VALUES
    assert query.geo.geoproperty == "https://uri.etsi.org/ngsi-ld/location"
    for bad in [
        {"type": "Query"},
        {"type": "Nope", "attrs": ["a"]},
        [],
        {"type": "Query", "attrs": [1]},
        {"type": "Query", "attrs": ["a"], "temporalQ": []},
        {"type": "Query", "attrs": ["a"], "x": 1},
        {"type": "Query", "entities": [{"idx": 1}]},
    ]:
        with pytest.raises(BadRequestData):
            query_from_body(bad, {}, "t", TERMS, limits=(100, 1000))
