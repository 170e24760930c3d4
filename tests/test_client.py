"""``tsdb_service.client`` against a real service (a uvicorn subprocess):
its DataFrames hold exactly what the HTTP API answers."""

from __future__ import annotations

from datetime import datetime

import httpx
import orjson
import pandas as pd
import pytest

from tests.export_fixtures import READ, TENANT, api_view, load, robot
from tests.support.server import ServerProcess
from tsdb_service.client import Client, TsdbClientError


class _Http:
    """httpx with the TestClient's ``get``/``post`` signature, for the shared fixtures."""

    def __init__(self, url: str):
        self._http = httpx.Client(base_url=url, timeout=30)

    def get(self, path, params=None, headers=None):
        return self._http.get(path, params=params, headers=headers)

    def post(self, path, json=None, headers=None):
        return self._http.post(path, json=json, headers=headers)


@pytest.fixture(scope="module")
def service(store_url_factory, tmp_path_factory):
    """One loaded service per backend for the whole module."""
    with ServerProcess(store_url_factory("client"), log_dir=tmp_path_factory.mktemp("client-logs")) as server:
        load(_Http(server.url))
        yield server


@pytest.fixture
def tsdb(service):
    with Client(service.url, service=TENANT) as client:
        yield client


def _json(service, path: str, params: dict | None = None, headers: dict = READ):
    response = httpx.get(service.url + path, params=params, headers=headers, timeout=30)
    assert response.status_code == 200, response.text
    return response.json()


def _times(iso: list[str]) -> list[pd.Timestamp]:
    return [pd.Timestamp(t) for t in iso]


def test_entities(tsdb, service):
    frame = tsdb.entities()
    expected = _json(service, "/v2/entities")
    assert list(frame.columns) == ["entity_id", "entity_type", "time"]
    assert list(zip(frame.entity_id, frame.entity_type, strict=True)) == [(e["id"], e["type"]) for e in expected]
    assert list(frame.time) == _times([e["index"] for e in expected])
    assert str(frame.time.dt.tz) == "UTC"
    assert list(tsdb.entities(entity_type="Sensor").entity_id) == ["Sensor:1"]


def test_entity_attr_last_n_and_value_path(tsdb, service):
    frame = tsdb.entity_attr("Robot:2", "odom(twist.linear.x)", last_n=3)
    expected = _json(service, "/v2/entities/Robot:2/attrs/odom(twist.linear.x)", {"lastN": 3})
    assert list(frame.columns) == ["odom(twist.linear.x)"]
    assert frame.index.name == "time"
    assert list(frame.index) == _times(expected["index"])
    assert list(frame["odom(twist.linear.x)"]) == expected["values"] == [0.5, 0.6, 0.7]


def test_entity_time_window_many_attrs(tsdb, service):
    window = {"from_date": "2024-05-01T10:00:02Z", "to_date": datetime(2024, 5, 1, 10, 0, 5)}
    frame = tsdb.entity("Robot:1", ["battery", "mode", "odom"], entity_type="Robot", **window)
    expected = _json(
        service,
        "/v2/entities/Robot:1",
        {
            "type": "Robot",
            "attrs": "battery,mode,odom",
            "fromDate": "2024-05-01T10:00:02Z",
            "toDate": "2024-05-01T10:00:05Z",
        },
    )
    assert list(frame.index) == _times(expected["index"])
    for attr in expected["attributes"]:
        assert list(frame[attr["attrName"]]) == attr["values"]
    assert frame["odom"].iloc[0] == {"twist": {"linear": {"x": 0.2}}, "tags": [1, "b", None]}


def test_raw_history_is_read_page_by_page(service):
    """A page far smaller than the history still returns all of it, in order."""
    with Client(service.url, service=TENANT, page_size=3) as small, Client(service.url, service=TENANT) as big:
        paged = small.entity("Robot:1", entity_type="Robot")
        whole = big.entity("Robot:1", entity_type="Robot")
        assert len(paged) == 8
        pd.testing.assert_frame_equal(paged, whole)
        assert len(small.entity("Robot:1", entity_type="Robot", limit=5, offset=2)) == 5
        typed = small.type_history("Robot", ["count"])
        assert len(typed) == 16
        pd.testing.assert_frame_equal(typed, big.type_history("Robot", ["count"]))


def test_aggregation_with_period(tsdb, service):
    frame = tsdb.entity_attr("Robot:2", "count", aggr_method="sum", aggr_period="minute")
    expected = _json(service, "/v2/entities/Robot:2/attrs/count", {"aggrMethod": "sum", "aggrPeriod": "minute"})
    assert list(frame.index) == _times(expected["index"])
    assert list(frame["count"]) == expected["values"] == [sum(i * 1000 for i in range(8))]
    one = tsdb.entity("Robot:2", ["battery"], aggr_method="max")  # no period: one row, no times
    assert one["battery"].tolist() == [90.5]


def test_type_history(tsdb, service):
    frame = tsdb.type_history("Robot", ["battery", "docked"], last_n=2)
    expected = _json(service, "/v2/types/Robot", {"attrs": "battery,docked", "lastN": 2})
    rows = [
        (ent["id"], pd.Timestamp(t), *[a["values"][i] for a in ent["attributes"]])
        for ent in expected["entities"]
        for i, t in enumerate(ent["index"])
    ]
    assert list(frame.columns) == ["entity_id", "time", "battery", "docked"]
    assert [tuple(r) for r in frame.itertuples(index=False)] == rows
    scoped = Client(service.url, service=TENANT, service_path="/site/b")
    with scoped:
        assert set(scoped.type_history("Robot", ["count"]).entity_id) == {"Robot:2"}
    glob = tsdb.type_history("Robot", ["count"], aggr_method="count", aggr_scope="global")
    assert glob.entity_id.tolist() == ["Robot:1,Robot:2"] and glob["count"].tolist() == [16]


def test_export_to_dataframe(tsdb, service):
    frame = tsdb.export(entity_type=["Robot", "Sensor"], attrs=["battery", "humidity", "odom"])
    expected = api_view(_Http(service.url), {"type": "Robot,Sensor", "attrs": "battery,humidity,odom"}, READ)
    assert list(frame.columns) == [
        "time",
        "entity_id",
        "entity_type",
        "service_path",
        "attribute",
        "ngsi_type",
        "value_number",
        "value_text",
        "value_bool",
        "value_json",
    ]
    assert str(frame.time.dt.tz) == "UTC"
    got = {}
    for row in frame.itertuples(index=False):
        value = row.value_number if pd.notna(row.value_number) else orjson.loads(row.value_json)
        iso = row.time.strftime("%Y-%m-%dT%H:%M:%S.") + f"{row.time.microsecond // 1000:03d}+00:00"
        got.setdefault((row.entity_type, row.entity_id, row.attribute), []).append((iso, value))
    assert got == expected


def test_export_file_csv(tsdb, tmp_path):
    path = tsdb.export_file(tmp_path / "robot2.csv", format="csv", entity_id="Robot:2", attrs=["mode"])
    frame = pd.read_csv(path, keep_default_na=False)
    assert frame["value_text"].tolist() == [robot(i, "Robot:2")["data"][0]["mode"]["value"] for i in range(8)]
    assert set(frame.service_path) == {"/site/b"}


def test_errors_carry_the_ngsi_answer(tsdb):
    with pytest.raises(TsdbClientError) as caught:
        tsdb.entity_attr("Robot:2", "count", aggr_method="median")
    assert caught.value.status == 400 and "aggrMethod" in caught.value.description
    with pytest.raises(TsdbClientError, match="format must be csv, parquet or mcap"):
        tsdb.export_file("/dev/null", format="xlsx")


def test_empty_answers_are_empty_frames(tsdb):
    assert tsdb.entity_attr("Nobody", "count").empty
    assert tsdb.entity("Nobody").empty
    assert tsdb.type_history("Nothing").empty
    assert tsdb.entities(entity_type="Nothing").empty
