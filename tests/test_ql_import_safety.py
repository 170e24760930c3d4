"""``import quantumleap`` is as safe as ``copy``: it refuses, resumes and checks.

A QuantumLeap database is built in the test PostgreSQL in QuantumLeap's
layout (``commands.quantumleap.layout``), with the odd rows QuantumLeap
itself writes: a duplicate (it does not deduplicate), a failed batch's rows
(only ``__original_ngsi_entity__`` filled), one of them unparseable, and a
row whose attribute columns are all NULL. Then: a non-empty target is
refused without ``--append``; ``--dry-run`` writes nothing; an interrupted
import resumes without duplicates; filters let a site move in steps; a wrong
URL, a database without QuantumLeap's tables and a half-migrated target are
each one ``error:`` line and exit status 2.
"""

from __future__ import annotations

import itertools
import json
from datetime import UTC, datetime, timedelta
from pathlib import Path

import psycopg
import pytest

from tests.support.interrupt import Interrupted, InterruptedTarget
from tsdb_service.cli.main import main
from tsdb_service.commands.quantumleap.importer import ImportRefused, Selection, import_quantumleap
from tsdb_service.commands.quantumleap.layout import insert_rows, table_name, write_entities
from tsdb_service.commands.quantumleap.reader import Window
from tsdb_service.core.config import Settings
from tsdb_service.core.model import AttrSample, EntitySample, Kind
from tsdb_service.storage import open_store
from tsdb_service.write.ops import AppendSamples

T0 = datetime(2024, 5, 1, 10, tzinfo=UTC)
ROOMS, LAMPS = 30, 20  # rows; a room row has 2 samples, a lamp row 1
_names = itertools.count()


def _room(i: int) -> dict:
    return {
        "id": f"Room{i % 3}",
        "type": "Room",
        "temperature": {"type": "Number", "value": 20 + i / 10},
        "name": {"type": "Text", "value": f"room {i % 3}"},
    }


@pytest.fixture
def ql(pg_cluster) -> str:
    """A QuantumLeap database: tenant acme's Rooms, the default tenant's Lamps, and odd rows."""
    url = pg_cluster.database(f"ql_source_{next(_names)}")
    with psycopg.connect(url, autocommit=True) as conn:
        write_entities(conn, "acme", [(_room(i), T0 + timedelta(minutes=i), "/site") for i in range(ROOMS)])
        lamps = [{"id": "Lamp:1", "type": "Lamp", "on": {"type": "Boolean", "value": i % 2 == 0}} for i in range(LAMPS)]
        write_entities(conn, "", [(lamp, T0 + timedelta(minutes=i), "/") for i, lamp in enumerate(lamps)])
        rooms = table_name("acme", "Room")
        twice = {"entity_id": "Room0", "entity_type": "Room", "time_index": T0, "fiware_servicepath": "/site"}
        insert_rows(conn, rooms, [{**twice, "temperature": 20.0, "name": "room 0", "instanceid": "urn:again"}])
        original = {"id": "Room9", "type": "Room", "time_index": "2024-04-30T08:00:00+00:00"}
        original["temperature"] = {"type": "Number", "value": 5}
        failed = {"entity_id": "Room9", "entity_type": "Room", "time_index": T0 + timedelta(hours=2)}
        wrapper = {"data": original, "error": "ProgrammingError()", "failedBatchID": "b1"}
        insert_rows(conn, rooms, [{**failed, "__original_ngsi_entity__": json.dumps(wrapper)}])
        broken = {"data": "{cut", "error": "ProgrammingError()", "failedBatchID": "b1"}
        insert_rows(conn, rooms, [{**failed, "entity_id": "Room8", "__original_ngsi_entity__": json.dumps(broken)}])
        insert_rows(conn, rooms, [{**twice, "time_index": T0 + timedelta(hours=3)}])  # every attribute NULL
    return url


# Rows and samples the fixture's import stores: rooms (+1 recovered), lamps.
EXPECTED = {("acme", "Room"): (ROOMS + 1, 2 * ROOMS + 1), ("", "Lamp"): (LAMPS, LAMPS)}


def _counts(db: str) -> dict[tuple[str, str], tuple[int, int]]:
    store = open_store(Settings(db=db))
    try:
        return store.querier().type_counts()
    finally:
        store.close()


def _run(capsys, *args: str) -> tuple[int, str, str]:
    code = main(["import", "quantumleap", *args, "--quiet"])
    out, err = capsys.readouterr()
    return code, out, err


def _one_error(code: int, err: str) -> str:
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1 and lines[0].startswith("error: "), err
    return lines[0]


def test_odd_rows_are_reported_and_imported_once(ql, tmp_path, capsys):
    db = str(tmp_path / "t.duckdb")
    code, out, _ = _run(capsys, "--from", ql, "--db", db)
    assert code == 0 and "import verified" in out
    assert _counts(db) == EXPECTED
    assert '"mtacme"."etroom": 34 rows, imported 31 rows, 61 samples' in out
    assert "1 duplicate rows, 1 failed-batch rows recovered, 2 rows not importable" in out
    assert "Room8" in out and "cannot be parsed" in out and "every attribute column is NULL" in out


def test_keep_duplicates_imports_them_as_stored(ql, tmp_path, capsys):
    db = str(tmp_path / "t.duckdb")
    assert _run(capsys, "--from", ql, "--db", db, "--keep-duplicates")[0] == 0
    assert _counts(db)[("acme", "Room")] == (ROOMS + 2, 2 * ROOMS + 3)


def test_a_non_empty_target_is_refused_without_append(ql, tmp_path, capsys):
    db = str(tmp_path / "t.duckdb")
    assert _run(capsys, "--from", ql, "--db", db)[0] == 0
    code, out, err = _run(capsys, "--from", ql, "--db", db)
    assert "--append" in _one_error(code, err) and "verified" not in out
    assert _counts(db) == EXPECTED, "a refused import writes nothing"


def test_dry_run_changes_nothing(ql, tmp_path, capsys):
    db = tmp_path / "never.duckdb"
    code, out, _ = _run(capsys, "--from", ql, "--db", str(db), "--dry-run")
    assert code == 0 and not db.exists(), "the target is not even created"
    assert '"etlamp": 20 rows, would import 20 rows, 20 samples' in out
    assert "dry run: 81 samples would be imported; nothing was written" in out


def test_a_site_moves_in_steps_without_gap_or_overlap(ql, tmp_path, capsys):
    """Import up to a time, (switch Orion), import the gap with --append; by tenant, by type."""
    db = str(tmp_path / "t.duckdb")
    cut = (T0 + timedelta(minutes=10)).isoformat()
    assert _run(capsys, "--from", ql, "--db", db, "--tenant", "acme", "--to-date", cut)[0] == 0
    # Rows are chosen by QuantumLeap's time_index: the failed batch's row was
    # written after the cut, so its recovered entity comes with the gap.
    assert _counts(db) == {("acme", "Room"): (10, 20)}
    assert _run(capsys, "--from", ql, "--db", db, "--tenant", "acme", "--from-date", cut, "--append")[0] == 0
    assert _run(capsys, "--from", ql, "--db", db, "--type", "Lamp", "--append")[0] == 0
    assert _counts(db) == EXPECTED


class _Serving:
    """The real target while it serves: every batch the import commits, a
    live notification (timed after the cut) is committed too."""

    def __init__(self, store, live_from: datetime):
        self._store, self._live = store, itertools.count()
        self._live_from = live_from

    def __getattr__(self, name):
        return getattr(self._store, name)

    def write_sync(self, ops):
        self._store.write_sync(ops)
        moment = self._live_from + timedelta(seconds=next(self._live))
        live = EntitySample(
            "acme", "/site", "Room0", "Room", moment, [AttrSample("temperature", "Number", Kind.NUMBER, num=1.0)]
        )
        self._store.write_sync([AppendSamples([live])])


def test_the_gap_is_imported_into_a_serving_target(ql, tmp_path):
    """After the switch the target receives notifications while the gap is
    imported: the check counts what is timed before --to-date."""
    db = str(tmp_path / "t.duckdb")
    cut, switch = T0 + timedelta(minutes=10), T0 + timedelta(minutes=20)
    store = open_store(Settings(db=db))
    try:
        import_quantumleap(ql, store, selection=Selection(window=Window(end=cut)))
        serving = _Serving(store, switch)
        gap = Selection(window=Window(cut, switch))
        report = import_quantumleap(ql, serving, selection=gap, append=True, batch_samples=10)  # type: ignore[arg-type]
        assert report.totals[("acme", "Room")] == (20, 40)
        assert store.querier().type_counts(switch) == {("acme", "Room"): (20, 40), ("", "Lamp"): (LAMPS, LAMPS)}
    finally:
        store.close()


@pytest.mark.parametrize("backend", ["duckdb", "postgresql"])
def test_an_interrupted_import_resumes_without_duplicates(ql, tmp_path, pg_cluster, backend, capsys):
    db = str(tmp_path / "t.duckdb") if backend == "duckdb" else pg_cluster.database(f"ql_target_{next(_names)}")
    store = open_store(Settings(db=db))
    try:
        with pytest.raises(Interrupted):
            import_quantumleap(ql, InterruptedTarget(store, 2), batch_samples=10, page_rows=7)  # type: ignore[arg-type]
        partial = sum(n for _, n in store.querier().type_counts().values())
        assert 0 < partial < 81
        with pytest.raises(ImportRefused, match="interrupted import"):
            import_quantumleap(ql, store, selection=Selection(tenants=("acme",)))
        report = import_quantumleap(ql, store, batch_samples=10, page_rows=7)
        assert report.resumed_from == partial
        assert store.querier().type_counts() == EXPECTED
    finally:
        store.close()
    code, _, err = _run(capsys, "--from", ql, "--db", db, "--append")
    assert code == 0, err  # the finished run is closed: a new one may start


def test_a_half_migrated_target_is_one_line(ql, tmp_path, capsys):
    db = str(tmp_path / "t.duckdb")
    store = open_store(Settings(db=db))
    try:
        with pytest.raises(Interrupted):
            import_quantumleap(ql, InterruptedTarget(store, 1), batch_samples=10)  # type: ignore[arg-type]
    finally:
        store.close()
    code, _, err = _run(capsys, "--from", ql, "--db", db, "--tenant", "acme")
    assert "interrupted import" in _one_error(code, err)
    other = str(tmp_path / "other.duckdb")
    store = open_store(Settings(db=other))
    try:
        one = [AttrSample("temperature", "Number", Kind.NUMBER, num=1.0)]
        store.write_sync([AppendSamples([EntitySample("acme", "/", "Room0", "Room", T0, one)])])
    finally:
        store.close()
    code = main(["copy", "--from", other, "--to", db, "--quiet"])
    assert "tsdb-service import quantumleap" in _one_error(code, capsys.readouterr().err), "copy says which command"


def test_a_wrong_url_is_one_line(tmp_path, capsys, pg_cluster):
    db = tmp_path / "t.duckdb"
    wrong = pg_cluster.url.rsplit("/", 1)[0] + "/no_such_database"
    assert "cannot connect" in _one_error(*_run(capsys, "--from", wrong, "--db", str(db))[::2])
    assert "postgresql://" in _one_error(*_run(capsys, "--from", "crate://host:4200", "--db", str(db))[::2])
    assert not db.exists(), "nothing is created"


def test_a_database_without_quantumleap_tables_is_one_line(tmp_path, capsys, pg_cluster):
    empty = pg_cluster.database(f"not_ql_{next(_names)}")
    db: Path = tmp_path / "t.duckdb"
    assert "no QuantumLeap tables" in _one_error(*_run(capsys, "--from", empty, "--db", str(db))[::2])
    assert not db.exists()
