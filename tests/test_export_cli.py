"""``tsdb-service export``: a real file that reads back as the API's answer."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.export_fixtures import (
    READ,
    TENANT,
    api_view,
    export_view,
    load,
    read_csv,
    read_parquet,
)
from tsdb_service.cli.main import main
from tsdb_service.faces.export import ExportFormat, SampleStream, write_file


@pytest.fixture
def stored(client_factory, store_url):
    """A store with the export data set, closed again (a DuckDB file has one owner)."""
    with client_factory(store_url) as client:
        load(client)
        expected = api_view(client, {"type": "Robot", "attrs": "battery,mode,odom"}, READ)
        everything = api_view(client, {}, READ)
    return store_url, expected, everything


def test_parquet_file_equals_the_api(stored, tmp_path, capsys):
    url, expected, _ = stored
    out = tmp_path / "robots.parquet"
    args = [
        "export",
        "--db",
        url,
        "--out",
        str(out),
        "--service",
        TENANT,
        "--type",
        "Robot",
        "--attrs",
        "battery,mode,odom",
    ]
    assert main(args) == 0
    assert export_view(read_parquet(out.read_bytes())) == expected
    said = capsys.readouterr().out
    assert f"exported {sum(map(len, expected.values()))} samples to {out}" in said
    assert "samples/s" in said
    assert not list(tmp_path.glob("*.partial"))


def test_csv_by_suffix_whole_tenant(stored, tmp_path):
    url, _, everything = stored
    out = tmp_path / "all.csv"
    assert main(["export", "--db", url, "--out", str(out), "--service", TENANT.upper()]) == 0
    assert out.read_bytes().startswith(b'"time","entity_id"')
    assert export_view(read_csv(out.read_bytes())) == everything


def test_time_range_and_service_path(stored, tmp_path):
    url, _, _ = stored
    out = tmp_path / "b.dat"
    args = [
        "export",
        "--db",
        url,
        "--out",
        str(out),
        "--format",
        "parquet",
        "--service",
        TENANT,
        "--service-path",
        "/site/b",
        "--id",
        "Robot:2",
        "--attrs",
        "count",
        "--from-date",
        "2024-05-01T10:00:02Z",
        "--to-date",
        "2024-05-01T10:00:04Z",
    ]
    assert main(args) == 0
    rows = read_parquet(out.read_bytes()).to_pylist()
    assert [r["value_number"] for r in rows] == [2000.0, 3000.0]
    assert {r["service_path"] for r in rows} == {"/site/b"}


def test_by_bucket(stored, tmp_path, capsys):
    """``--bucket 1h``: one row per series and hour holding numbers, as the API's ``bucket=1h``."""
    url, _, _ = stored
    out = tmp_path / "hourly.parquet"
    args = ["export", "--db", url, "--out", str(out), "--service", TENANT, "--attrs", "count", "--bucket", "1h"]
    assert main(args) == 0
    rows = read_parquet(out.read_bytes()).to_pylist()
    assert rows and list(rows[0]) == [
        "time", "entity_id", "entity_type", "service_path", "attribute", "n", "avg", "min", "max", "first", "last"
    ]  # fmt: skip
    assert all(r["attribute"] == "count" and r["n"] >= 1 and r["min"] <= r["avg"] <= r["max"] for r in rows)
    assert all(r["time"].minute == 0 and r["time"].second == 0 for r in rows)
    assert f"exported {len(rows)} buckets to {out}" in capsys.readouterr().out
    assert main([*args[:-1], "2 hours"]) == 2


def test_a_missing_database_is_an_error(tmp_path, capsys):
    missing = tmp_path / "nope.duckdb"
    assert main(["export", "--db", str(missing), "--out", str(tmp_path / "x.csv")]) == 2
    assert "no database at" in capsys.readouterr().err
    assert not missing.exists() and not (tmp_path / "x.csv").exists()


def test_bad_parameters_are_one_line(stored, tmp_path, capsys):
    url, _, _ = stored
    assert main(["export", "--db", url, "--out", str(tmp_path / "x.csv"), "--from-date", "soon"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: fromDate must be an ISO 8601") and err.count("\n") == 1


def test_an_interrupted_export_leaves_no_file(tmp_path):
    """A cut-short export (here: the disk fills after one batch) removes its partial file."""
    one_row = read_csv(
        b'"time","entity_id","entity_type","service_path","attribute","ngsi_type",'
        b'"value_number","value_text","value_bool","value_json"\n'
        b'2024-05-01 10:00:00.000001Z,"E","T","/","a","Number",1,,,\n'
    ).to_batches()
    handed = iter(one_row)

    def next_or_fail():
        batch = next(handed, None)
        if batch is None:
            raise OSError("disk full")
        return batch

    stream = SampleStream()
    stream._next = next_or_fail
    with pytest.raises(OSError, match="disk full"):
        write_file(stream, ExportFormat.CSV, tmp_path / "cut.csv")
    assert list(Path(tmp_path).iterdir()) == []


@pytest.mark.parametrize(
    ("out", "says"),
    [
        ("x.json", "x.json: the suffix '.json' names no export format; end it in .csv, .parquet or .mcap"),
        (
            "history",
            "history: a name without a suffix says no format; end it in .csv, .parquet or .mcap, or give --format",
        ),
        ("missing/dir/x.csv", "does not exist"),
        (".", "is a directory"),
    ],
)
def test_a_bad_out_is_one_line_before_the_database_is_opened(stored, tmp_path, capsys, monkeypatch, out, says):
    """``--out x.json`` wrote CSV silently; a missing directory ended in a traceback."""
    url, _, _ = stored
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr("tsdb_service.storage.open_store", _never_opened)
    assert main(["export", "--db", url, "--out", out]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"error: --out {out}") and says in err and err.count("\n") == 1, err
    assert sorted(p.name for p in tmp_path.iterdir() if not p.name.endswith((".duckdb", ".wal"))) == []


def _never_opened(*_args, **_kwargs):
    raise AssertionError("the database was opened for an export that cannot be written")


def test_the_format_flag_wins_over_the_suffix(stored, tmp_path):
    url, _, _ = stored
    out = tmp_path / "history.json"
    assert main(["export", "--db", url, "--out", str(out), "--service", TENANT, "--format", "csv"]) == 0
    assert out.read_bytes().startswith(b'"time","entity_id"')


def test_a_suffix_naming_another_format_than_the_flag_is_refused(stored, tmp_path, capsys):
    url, _, _ = stored
    out = tmp_path / "history.csv"
    assert main(["export", "--db", url, "--out", str(out), "--service", TENANT, "--format", "mcap"]) == 2
    err = capsys.readouterr().err
    assert err == f"error: --out {out} names csv but --format says mcap: make them agree\n", err
    assert not out.exists()


def test_an_empty_export_names_the_tenants_with_data(stored, tmp_path, capsys):
    """The demo's data is under lawnmower, warehouse, drone: without --service
    (or with a mistyped one) an export found nothing and said only "0 samples"."""
    url, _, _ = stored
    assert main(["export", "--db", url, "--out", str(tmp_path / "none.csv")]) == 0
    said = capsys.readouterr()
    assert "exported 0 samples" in said.out
    hint = "hint: the default tenant (no Fiware-Service) holds no data; tenants with data: elsewhere, exportland"
    assert said.err == hint + " (--service TENANT)\n"
    assert main(["export", "--db", url, "--out", str(tmp_path / "typo.csv"), "--service", TENANT + "x"]) == 0
    assert f"hint: tenant '{TENANT}x' holds no data; tenants with data: elsewhere, {TENANT}" in capsys.readouterr().err
    assert main(["export", "--db", url, "--out", str(tmp_path / "some.csv"), "--service", TENANT]) == 0
    assert capsys.readouterr().err == ""
