"""After ``import quantumleap``, our QuantumLeap API answers as QuantumLeap did.

The golden ``main`` dataset (tests/golden/notifications/main) is written in
QuantumLeap's PostgreSQL layout (``commands.quantumleap.layout``: a table per
tenant and type, lower-cased columns, ``md_ets_metadata``), imported, and
every read case recorded for it (tests/golden/cases: QuantumLeap's
documented answers for that data) is asked of the imported store. The
answers must be the golden ones, and the same as a store that received the
notifications through ``/v2/notify``. Without PostGIS the geometry
attributes are left out of both (QuantumLeap's layout needs PostGIS for
them), and then only the comparison with ``/v2/notify`` is made.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import psycopg
import pytest

from tests.support.rollups import differences
from tsdb_service.cli.main import main
from tsdb_service.commands.quantumleap.layout import has_postgis, write_entities
from tsdb_service.parse.timeindex import parse_time

GOLDEN = Path(__file__).parent / "golden"
GEO_TYPES = {"geo:json", "geo:point", "geo:line", "geo:polygon", "geo:box", "GeoProperty"}


def _notifications(with_geo: bool) -> list[dict]:
    """The dataset's notifications, in order; without geometry attributes unless ``with_geo``."""
    out = []
    for path in sorted((GOLDEN / "notifications" / "main").glob("*.json")):
        note = json.loads(path.read_text())
        for entity in note["body"]["data"]:
            for name in [k for k, v in entity.items() if isinstance(v, dict) and _left_out(v, with_geo)]:
                del entity[name]
        out.append(note)
    return out


def _left_out(attr: dict, with_geo: bool) -> bool:
    """A ``null`` value is left out: QuantumLeap stores it as a NULL column,
    which cannot be told from an absent attribute (docs/quantumleap.md,
    "Details that differ": rows whose selected columns are all null)."""
    return attr.get("value") is None or (not with_geo and attr.get("type") in GEO_TYPES)


def _write_ql_layout(url: str, notes: list[dict]) -> None:
    """What QuantumLeap stores for the notifications: time index from
    ``TimeInstant`` (its reporter's choice when there is no custom header)."""
    with psycopg.connect(url, autocommit=True) as conn:
        for note in notes:
            headers = note.get("headers") or {}
            tenant = headers.get("Fiware-Service", "").lower()
            path = headers.get("Fiware-ServicePath", "/")
            rows = []
            for entity in note["body"]["data"]:
                moment = parse_time(entity["TimeInstant"]["value"])
                assert moment is not None, "every golden entity has a TimeInstant"
                rows.append((entity, moment, path))
            write_entities(conn, tenant, rows)


# QuantumLeap keeps one column type per attribute: Meter:1's ``reading``
# turns from Number to Text and QuantumLeap stores NULL for the text (its
# issue #778), so that history is not in its tables and cannot be imported.
LOST_IN_QUANTUMLEAP = ("Meter",)


def _read_cases() -> list[dict]:
    cases = []
    for path in sorted((GOLDEN / "cases").glob("*.json")):
        doc = json.loads(path.read_text())
        if doc["dataset"] == "main" and doc.get("mode", "independent") == "independent":
            cases += [
                c
                for c in doc["cases"]
                if c.get("method", "GET") == "GET" and not any(lost in c["path"] for lost in LOST_IN_QUANTUMLEAP)
            ]
    return cases


def _answers(client, cases: list[dict]) -> list[tuple]:
    out = []
    for case in cases:
        response = client.get(case["path"], headers=case.get("headers") or {})
        out.append((case["name"], case["path"], response.status_code, response.json() if response.content else None))
    return out


def test_imported_history_answers_like_quantumleap(pg_cluster, client_factory, tmp_path, capsys):
    source = pg_cluster.database("ql_parity_source")
    with psycopg.connect(source, autocommit=True) as conn:
        with_geo = _try_postgis(conn)
    notes = _notifications(with_geo)
    _write_ql_layout(source, notes)

    target = str(tmp_path / "imported.duckdb")
    assert main(["import", "quantumleap", "--from", source, "--db", target, "--quiet"]) == 0
    assert "import verified" in capsys.readouterr().out

    cases = _read_cases()
    assert len(cases) > 100
    with client_factory(target) as client:
        imported = _answers(client, cases)
        assert not differences(client.app.state.store)  # rolled up by the writers the import goes through
    with client_factory(str(tmp_path / "notified.duckdb")) as client:
        for note in notes:
            posted = client.post("/v2/notify", json=note["body"], headers=note.get("headers") or {})
            assert posted.status_code == 200
        notified = _answers(client, cases)
    differ = [(a, b) for a, b in zip(imported, _as_quantumleap(notified), strict=True) if a != b]
    assert differ == []


_RECEIVED_UTC = re.compile(r'"(\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d\.\d{3})Z"')


def _as_quantumleap(answers: list[tuple]) -> list[tuple]:
    """Our answers for notified data, with a ``DateTime`` attribute's value
    spelled as QuantumLeap answers it (read back from its timestamp column:
    UTC, milliseconds, ``+00:00``) where we answer the text as received."""
    return [tuple(a) for a in json.loads(_RECEIVED_UTC.sub(r'"\1+00:00"', json.dumps(answers)))]


def _try_postgis(conn) -> bool:
    try:
        conn.execute("CREATE EXTENSION IF NOT EXISTS postgis")
    except psycopg.Error:
        return False
    return has_postgis(conn)


@pytest.mark.parametrize("with_geo", [False])
def test_the_dataset_without_geometry_still_has_every_other_type(with_geo):
    """The comparison above stays meaningful without PostGIS: numbers,
    integers, text, booleans, dates, objects and FIROS values remain."""
    types = {
        v["type"]
        for note in _notifications(with_geo)
        for entity in note["body"]["data"]
        for v in entity.values()
        if isinstance(v, dict)
    }
    assert {"Number", "Integer", "Text", "Boolean", "DateTime"} <= types
