"""``import quantumleap`` on hostile or odd tables (issue 37, findings 7 and 8).

Finding 7: QuantumLeap keeps names our ingest refuses (a newline in an
entity id, quotes and SQL in an attribute name, a tenant outside the tenant
rule, a service path with a space); imported, the API could neither read
nor delete them. Now each is refused, counted and named in the report, and
everything stored passes the same rules as a notification.

Finding 8: malformed ``md_ets_metadata`` entries, column types QuantumLeap
never writes (``numeric``, ``interval``, ``bytea``, ``uuid``, arrays,
``money``), columns the metadata names and the table lacks, a table
without ``time_index``: tracebacks before; a NULL ``time_index`` over more
than one page: an endless loop; ``infinity`` and BC dates: the whole
import stopped; a 64 MiB text cell: 6.6 GB of memory. Now each is a line
of the report (skipped and counted), and the big cell is never read.

The QuantumLeap database is built in the private PostgreSQL cluster with
QuantumLeap's layout (``commands.quantumleap.layout``), then damaged.
"""

from __future__ import annotations

import itertools
import json
import os
import subprocess
import sys
import tempfile
from datetime import UTC, datetime, timedelta

import duckdb
import psycopg
import pytest

from tests.support.memory import peak_rss_mib
from tsdb_service.cli.main import main
from tsdb_service.commands.quantumleap.layout import insert_rows, table_name, write_entities
from tsdb_service.core.config import Settings
from tsdb_service.parse.names import id_problem, name_problem, service_path_problem
from tsdb_service.parse.request_context import is_stored_tenant
from tsdb_service.storage import open_store

T0 = datetime(2024, 5, 1, 10, tzinfo=UTC)
_names = itertools.count()
SQL_NAME = 'x"); DROP TABLE md_ets_metadata; --'


def _md(conn, name: str, entity_attrs) -> None:
    conn.execute("INSERT INTO md_ets_metadata VALUES (%s, %s)", [name, entity_attrs])


def _table(conn, name: str, columns: str, attrs: dict) -> None:
    conn.execute(f"CREATE TABLE {name} ({columns})")
    _md(conn, name, json.dumps(attrs))


@pytest.fixture
def hostile(pg_cluster) -> str:
    url = pg_cluster.database(f"ql_hostile_{next(_names)}")
    with psycopg.connect(url, autocommit=True) as conn:
        good = {"id": "Room1", "type": "Room", "temperature": {"type": "Number", "value": 21.5}}
        write_entities(conn, "acme", [(good, T0 + timedelta(minutes=i), "/site") for i in range(3)])
        # Finding 7: names the ingest refuses.
        robot = {"id": "Robot1", "type": "Robot", "speed": {"type": "Number", "value": 1.0}}
        robot[SQL_NAME] = {"type": "Text", "value": "sql"}
        write_entities(conn, "acme", [(robot, T0, "/site")])
        robots = table_name("acme", "Robot")
        row = {"entity_type": "Robot", "time_index": T0 + timedelta(minutes=1), "speed": 2.0, "fiware_servicepath": "/"}
        insert_rows(conn, robots, [{**row, "entity_id": "Robot\n2"}])  # a newline in the id
        insert_rows(conn, robots, [{**row, "entity_id": "Robot3", "fiware_servicepath": "/a b"}])
        insert_rows(conn, robots, [{**row, "entity_id": "Robot4", "entity_type": "Ro,bot"}])
        write_entities(
            conn, "bad-tenant", [({"id": "X1", "type": "Room", "t": {"type": "Number", "value": 1}}, T0, "/")]
        )
        # Finding 8: malformed metadata entries.
        _md(conn, '"etarray"', "[1, 2]")
        _md(conn, '"etnull"', None)
        _table(
            conn,
            '"etodd"',
            "entity_id text, entity_type text, time_index timestamptz, n numeric, i interval, b bytea, u uuid, "
            "a int[], m money, w float",
            {
                "n": ["n", "Number"],
                "i": ["i", "Text"],
                "b": ["b", "Text"],
                "u": ["u", "Text"],
                "a": ["a", "Array"],
                "m": ["m", "Number"],
                "ghost": ["ghost", "Number"],  # no such column
                "w": 7,  # not [name, type]
            },
        )
        conn.execute(
            """INSERT INTO "etodd" VALUES ('Odd1', 'Odd', %s, 1.25, '1 day 02:03:04', '\\x00ff',
            'a0eebc99-9c0b-4ef8-bb6d-6bb9bd380a11', '{1,2}', 12.5, 3.0)""",
            [T0],
        )
        _table(conn, '"etnotime"', "entity_id text, entity_type text, v float", {"v": ["v", "Number"]})
        conn.execute("""INSERT INTO "etnotime" VALUES ('N', 'N', 1)""")
        _table(
            conn,
            '"etuntimed"',
            "entity_id text, entity_type text, time_index timestamptz, v float",
            {"v": ["v", "Number"]},
        )
        conn.execute("""INSERT INTO "etuntimed" SELECT 'U', 'U', NULL, g FROM generate_series(1, 25) g""")
        conn.execute("""INSERT INTO "etuntimed" VALUES ('U', 'U', %s, 99)""", [T0])
        _table(
            conn,
            '"etinf"',
            "entity_id text, entity_type text, time_index timestamptz, d timestamptz, v float",
            {"d": ["d", "DateTime"], "v": ["v", "Number"]},
        )
        conn.execute(
            """INSERT INTO "etinf" VALUES ('I', 'I', 'infinity', '2024-01-01', 1), ('I', 'I', '0044-03-15 BC', NULL, 2),
            ('I', 'I', '2024-01-02', '-infinity', 3), ('I', 'I', '2024-01-03', '0044-03-15 BC', 4),
            ('I', 'I', '2024-01-04', '2024-01-04', 5)"""
        )
    return url


def _run(capsys, *args: str) -> tuple[int, str, str]:
    code = main(["import", "quantumleap", *args, "--quiet"])
    out, err = capsys.readouterr()
    return code, out, err


def test_hostile_tables_give_a_report_and_only_names_the_api_can_serve(hostile, tmp_path, capsys):
    db = str(tmp_path / "t.duckdb")
    code, out, err = _run(capsys, "--from", hostile, "--db", db)
    assert code == 0 and "import verified" in out, out + err
    assert "Traceback" not in err
    # Finding 7: each refusal said, with its reason.
    assert '"mtbad-tenant"."etroom": not imported: tenant \'bad-tenant\' is not one the API serves' in out
    assert f"column {SQL_NAME.lower()!r} not imported: attribute name {SQL_NAME!r} contains" in out
    assert "not imported: Robot\\n2 at" in out and "entity id 'Robot\\n2' contains white space" in out
    assert "service path '/a b' contains white space" in out
    assert "entity type 'Ro,bot' contains ','" in out
    # Finding 8: each odd table or value a line, the rest imported.
    assert '"etarray": not imported: md_ets_metadata.entity_attrs is' in out
    assert '"etnull": not imported: md_ets_metadata.entity_attrs is NULL' in out
    assert "column 'ghost' not imported: attribute 'ghost': md_ets_metadata names it, the table has no such" in out
    assert "column 'w' not imported: md_ets_metadata describes it as '7'" in out
    assert '"etnotime": 1 rows, not imported: the table has no time_index column' in out
    assert '"etuntimed": 26 rows, imported 1 rows, 1 samples (25 rows not importable)' in out
    assert "25 rows at -: time_index is NULL, infinity or outside the years 1 to 9999" in out
    assert '"etinf": 5 rows, imported 3 rows, 4 samples (2 rows not importable, 2 values not importable)' in out
    assert "value not imported: 'd' of I at 2024-01-02T00:00:00.000+00:00: a time outside the years 1 to 9999" in out

    store = open_store(Settings(db=db))
    try:
        counts = store.querier().type_counts()
    finally:
        store.close()
    assert counts[("acme", "Room")] == (3, 3)
    assert counts[("acme", "Robot")] == (1, 1)  # Robot1's speed; its SQL-named attribute refused
    assert counts[("", "Odd")] == (1, 6)
    with duckdb.connect(db, read_only=True) as conn:
        series = conn.execute("SELECT tenant, service_path, entity_id, entity_type, attr FROM series").fetchall()
        odd = dict(
            conn.execute(
                "SELECT s.attr, coalesce(x.txt, x.js, CAST(x.num AS VARCHAR)) FROM series s "
                "JOIN samples_all x USING (sid) WHERE s.entity_id = 'Odd1'"
            ).fetchall()
        )
    for tenant, path, eid, etype, attr in series:  # every stored name reachable through the API
        assert is_stored_tenant(tenant) and service_path_problem(path) is None
        assert id_problem(eid) is None and id_problem(etype) is None and name_problem(attr) is None
    assert odd == {  # plain JSON values, whatever the column type
        "n": "1.25",
        "i": "P1DT2H3M4S",
        "b": "AP8=",
        "u": "a0eebc99-9c0b-4ef8-bb6d-6bb9bd380a11",
        "a": "[1,2]",
        "m": "$12.50",
    }


def test_a_dry_run_of_hostile_tables_is_a_report_too(hostile, tmp_path, capsys):
    code, out, err = _run(capsys, "--from", hostile, "--db", str(tmp_path / "never.duckdb"), "--dry-run")
    assert code == 0 and "Traceback" not in err and "dry run:" in out
    assert '"etuntimed": 26 rows, would import 1 rows' in out


def test_null_time_indexes_over_many_pages_end(hostile, tmp_path):
    """Pages of 10 rows: 25 rows without time_index once looped for ever."""
    from tsdb_service.commands.quantumleap.importer import Selection, import_quantumleap

    store = open_store(Settings(db=str(tmp_path / "t.duckdb")))
    try:
        report = import_quantumleap(hostile, store, selection=Selection(types=("untimed",)), page_rows=10)
    finally:
        store.close()
    (table,) = report.tables
    assert (table.rows, table.unreadable) == (1, 25)


def _peak_rss_mib(args: list[str]) -> tuple[int, int, str]:
    """Run the CLI in a process of its own: its exit status, peak RSS (MiB, sampled) and output."""
    with tempfile.TemporaryFile() as output:
        proc = subprocess.Popen(
            [sys.executable, "-m", "tsdb_service", *args],
            stdout=output,
            stderr=subprocess.STDOUT,
            env={k: v for k, v in os.environ.items() if not k.startswith("TSDB_")},
        )
        peak = peak_rss_mib(proc.pid)
        code = proc.wait()
        output.seek(0)
        return code, peak, output.read().decode()


def test_a_64_mib_cell_is_refused_without_being_read(pg_cluster, tmp_path):
    url = pg_cluster.database(f"ql_big_{next(_names)}")
    with psycopg.connect(url, autocommit=True) as conn:
        rows = [({"id": "Doc1", "type": "Doc", "body": {"type": "Text", "value": "small"}}, T0, "/")]
        write_entities(conn, "", rows)
        conn.execute(
            """INSERT INTO "etdoc" (entity_id, entity_type, time_index, body)
            VALUES ('Doc1', 'Doc', %s, repeat('x', 64 * 1024 * 1024))""",
            [T0 + timedelta(minutes=1)],
        )
    db = str(tmp_path / "t.duckdb")
    code, peak, output = _peak_rss_mib(["import", "quantumleap", "--from", url, "--db", db, "--quiet"])
    assert code == 0, output
    assert "value not imported: 'body' of Doc1 at" in output and "larger than 9437184 bytes" in output
    # A Python process with DuckDB, pyarrow and psycopg loaded is ~200 MiB;
    # reading the cell took 6.6 GB. The bound leaves room for the runtime.
    assert peak < 400, f"peak RSS {peak} MiB"
