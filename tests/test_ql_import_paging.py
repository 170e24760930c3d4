"""The reader pages QuantumLeap's rows by ``time_index`` without splitting an instant.

The importer commits and resumes at the end of a page's instants, so a
page must never cut the rows of one ``time_index`` in two, even when one
instant holds more rows than a page (a failed batch's rows all share the
time of the failure), and every row must be read exactly once.
"""

from __future__ import annotations

import itertools
from datetime import UTC, datetime, timedelta

import psycopg

from tsdb_service.commands.quantumleap.layout import write_entities
from tsdb_service.commands.quantumleap.reader import QuantumLeapReader, Window

T0 = datetime(2024, 5, 1, 10, tzinfo=UTC)


def _entity(i: int) -> dict:
    return {"id": f"Sensor:{i}", "type": "Sensor", "level": {"type": "Number", "value": float(i)}}


def test_pages_keep_each_instant_whole_and_read_every_row_once(pg_cluster):
    url = pg_cluster.database("ql_paging")
    crowded = T0 + timedelta(seconds=5)
    rows = [(_entity(i), T0 + timedelta(seconds=i % 10), "/") for i in range(40)]
    rows += [(_entity(100 + i), crowded, "/") for i in range(25)]  # one instant, more than a page
    with psycopg.connect(url, autocommit=True) as conn:
        write_entities(conn, "", rows)
    reader = QuantumLeapReader(url)
    try:
        (meta,) = reader.tables()
        pages = list(reader.pages(meta, ["entity_id", "time_index"], Window(), page_rows=10))
        windowed = list(reader.pages(meta, ["entity_id", "time_index"], Window(crowded, crowded + timedelta(1)), 10))
    finally:
        reader.close()
    seen = [r["entity_id"] for page in pages for r in page]
    assert sorted(seen) == sorted(e["id"] for e, _, _ in rows), "every row once"
    instants = [{r["time_index"] for r in page} for page in pages]
    for a, b in itertools.pairwise(instants):
        assert max(a) < min(b), "pages follow each other in time and never share an instant"
    assert sum(len(page) for page in windowed) == 5 * 4 + 25, "seconds 5-9 of the 40 rows, and the crowded instant"
