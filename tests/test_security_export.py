"""Issue 27: a CSV export must not carry formulas into a spreadsheet. Text
cells starting with ``=``, ``+``, ``-``, ``@``, tab or carriage return get a
leading ``'`` (OWASP, CSV injection); ``raw=true`` (``--raw``) writes them
as stored; Parquet is typed and left alone. On both backends, with the
values really stored."""

from __future__ import annotations

import csv
import io

import pyarrow.parquet as pq
import pytest

from tsdb_service.cli.main import main

HOSTILE = ['=HYPERLINK("http://evil.example","x")', "+1+2", "-2+3", "@SUM(A1)", "\tTAB", "\rCR", "plain", "a=b"]
H = {"Fiware-Service": "csv", "Content-Type": "application/json"}


def note() -> dict:
    attrs = {f"t{i}": {"type": "Text", "value": v} for i, v in enumerate(HOSTILE)}
    attrs["n"] = {"type": "Number", "value": -5}
    attrs["TimeInstant"] = {"type": "DateTime", "value": "2024-05-01T10:00:00Z"}
    return {"data": [{"id": "=cmd|' /C calc'!A0", "type": "Robot", **attrs}]}


@pytest.fixture
def stored(client, notify):
    notify(client, note(), H)
    return client


def cells(text: str) -> dict[str, dict[str, str]]:
    return {row["attribute"]: row for row in csv.DictReader(io.StringIO(text, newline=""))}


def test_csv_cells_that_start_like_formulas_are_neutralised(stored):
    got = stored.get("/v2/export", params={"format": "csv"}, headers=H)
    assert got.status_code == 200, got.text
    rows = cells(got.text)
    for i, value in enumerate(HOSTILE):
        expected = value if value[0] not in "=+-@\t\r" else "'" + value
        assert rows[f"t{i}"]["value_text"] == expected
    assert {row["entity_id"] for row in rows.values()} == {"'=cmd|' /C calc'!A0"}
    assert rows["n"]["value_number"] == "-5"  # numbers are numbers


def test_raw_csv_and_parquet_keep_what_is_stored(stored):
    raw = cells(stored.get("/v2/export", params={"format": "csv", "raw": "true"}, headers=H).text)
    assert [raw[f"t{i}"]["value_text"] for i in range(len(HOSTILE))] == HOSTILE
    parquet = pq.read_table(io.BytesIO(stored.get("/v2/export", params={"format": "parquet"}, headers=H).content))
    texts = {r["attribute"]: r["value_text"] for r in parquet.to_pylist()}
    assert [texts[f"t{i}"] for i in range(len(HOSTILE))] == HOSTILE
    assert stored.get("/v2/export", params={"raw": "yes"}, headers=H).status_code == 400


def test_the_export_command_neutralises_too(client_factory, tmp_path, notify):
    db = tmp_path / "tsdb.duckdb"
    with client_factory(str(db)) as client:
        notify(client, note(), H)
    for flags, first in (([], "'=HYPERLINK"), (["--raw"], "=HYPERLINK")):
        out = tmp_path / f"out{len(flags)}.csv"
        assert main(["export", "--db", str(db), "--service", "csv", "--out", str(out), *flags]) == 0
        rows = cells(out.read_bytes().decode())
        assert rows["t0"]["value_text"].startswith(first)
