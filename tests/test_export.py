"""``GET /v2/export``: CSV and Parquet read back equal the history API's answer.

For each selection (tenant, service path, type, id, id pattern, attributes,
time range) the export holds exactly the samples the API returns for the
same parameters: same entities, attributes, times and values.
"""

from __future__ import annotations

import io
from datetime import UTC, datetime

import pyarrow.parquet as pq
import pytest

from tests.export_fixtures import (
    H_A,
    H_B,
    READ,
    api_view,
    export_view,
    load,
    read_csv,
    read_parquet,
)
from tsdb_service.faces.export import stream as export_stream

SELECTIONS = [
    pytest.param({}, READ, id="whole-tenant"),
    pytest.param({}, H_B, id="service-path"),
    pytest.param({"type": "Robot"}, READ, id="type"),
    pytest.param({"type": "Robot,Sensor", "attrs": "battery,humidity,mode"}, READ, id="types-attrs"),
    pytest.param({"id": "Robot:1"}, READ, id="id-in-two-types"),
    pytest.param({"id": "Robot:1", "type": "Dock"}, READ, id="id-and-type"),
    pytest.param({"idPattern": "^Robot:[2]$"}, READ, id="id-pattern"),
    pytest.param(
        {"fromDate": "2024-05-01T10:00:02.250074Z", "toDate": "2024-05-01T12:00:05+02:00"},
        READ,
        id="time-range-inclusive",
    ),
    pytest.param({"type": "Robot", "attrs": "temperature,spare,odom,location"}, H_A, id="changing-and-null"),
]


@pytest.fixture(scope="module")
def loaded(client_factory, store_url_factory):
    """One loaded store per backend; every test here only reads it."""
    with client_factory(store_url_factory("export")) as client:
        load(client)
        yield client


def _export(client, fmt: str, params: dict, headers: dict):
    response = client.get("/v2/export", params={**params, "format": fmt}, headers=headers)
    assert response.status_code == 200, response.text
    return response


@pytest.mark.parametrize(("params", "headers"), SELECTIONS)
def test_parquet_and_csv_equal_the_api(loaded, params, headers):
    expected = api_view(loaded, params, headers)
    assert expected, "the selection should not be empty"
    parquet = read_parquet(_export(loaded, "parquet", params, headers).content)
    csv = read_csv(_export(loaded, "csv", params, headers).content)
    assert export_view(parquet) == expected
    assert export_view(csv) == expected
    assert parquet.equals(csv)


def test_rows_carry_names_service_paths_and_exact_times(loaded):
    table = read_parquet(_export(loaded, "parquet", {"id": "Robot:2", "attrs": "count"}, READ).content)
    rows = table.to_pylist()
    assert len(rows) == 8
    assert {(r["entity_type"], r["service_path"], r["ngsi_type"]) for r in rows} == {("Robot", "/site/b", "Integer")}
    # Microseconds survive (the API shows milliseconds), in UTC, oldest first.
    assert rows[3]["time"] == datetime(2024, 5, 1, 10, 0, 3, 250_111, tzinfo=UTC)
    assert [r["value_number"] for r in rows] == [i * 1000.0 for i in range(8)]


def test_headers_name_the_format_and_file(loaded):
    parquet = _export(loaded, "parquet", {}, READ)
    assert parquet.headers["content-type"] == "application/vnd.apache.parquet"
    assert parquet.headers["content-disposition"] == 'attachment; filename="tsdb-export.parquet"'
    assert parquet.content.startswith(b"PAR1") and parquet.content.endswith(b"PAR1")
    csv = loaded.get("/v2/export", headers=READ)  # CSV is the default
    assert csv.headers["content-type"] == "text/csv; charset=utf-8"
    assert csv.text.splitlines()[0] == (
        '"time","entity_id","entity_type","service_path","attribute","ngsi_type",'
        '"value_number","value_text","value_bool","value_json"'
    )


def test_other_tenants_never_leak(loaded):
    table = read_parquet(_export(loaded, "parquet", {}, {"Fiware-Service": "elsewhere"}).content)
    assert set(table.column("entity_id").to_pylist()) == {"Robot:1"}
    assert table.num_rows == 8 * 11
    ours = read_parquet(_export(loaded, "parquet", {}, READ).content)
    assert ours.num_rows == (8 * 2 + 4) * 11 + 8 * 3  # robots, docks, the sensor


@pytest.mark.parametrize("fmt", ["csv", "parquet"])
def test_empty_selection_is_an_empty_file_with_the_columns(loaded, fmt):
    response = _export(loaded, fmt, {"type": "Nothing"}, READ)
    table = read_parquet(response.content) if fmt == "parquet" else read_csv(response.content)
    assert table.num_rows == 0
    assert table.column_names == export_stream.SCHEMA.names


def test_large_exports_stream_in_batches(loaded, monkeypatch):
    """Many batches (row groups) and sort windows give the same rows as one."""
    whole = read_parquet(_export(loaded, "parquet", {}, READ).content)
    monkeypatch.setattr(export_stream, "BATCH_ROWS", 7)
    monkeypatch.setattr(export_stream, "WINDOW_ROWS", 5)  # DuckDB: windows of ~1 notification
    data = _export(loaded, "parquet", {}, READ).content
    assert pq.ParquetFile(io.BytesIO(data)).num_row_groups >= -(-whole.num_rows // 7)
    assert read_parquet(data).equals(whole)
    assert read_csv(_export(loaded, "csv", {}, READ).content).equals(whole)
