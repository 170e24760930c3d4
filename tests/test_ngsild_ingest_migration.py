"""Migration 0005 on a store with data from before it: every existing
sample gets a unique instance id, reads keep working, new samples get new ids."""

from __future__ import annotations

from datetime import UTC, datetime

import duckdb
import psycopg

from tsdb_service.core.config import Settings
from tsdb_service.core.model import AttrSample, EntitySample, Kind
from tsdb_service.core.query import EntityFilter, Scope
from tsdb_service.read.requests import InstancesRead, SeriesSelect
from tsdb_service.storage import open_store
from tsdb_service.storage.migrations import SCHEMA_TABLE, load_migrations, split_statements
from tsdb_service.write.ops import AppendSamples

OLD_ROWS = [
    (1, 1, "2024-01-01 00:00:00", 1, "Number", 1.5),
    (1, 2, "2024-01-01 00:00:00", 1, "Number", 2.5),
    (2, 1, "2024-01-02 00:00:00", 1, "Number", 3.5),
]


def _old_store(url: str, backend: str) -> None:
    """A store migrated up to 0004, with samples in it."""
    old = [m for m in load_migrations(backend) if m.version < 5]
    series = "INSERT INTO series (sid, tenant, service_path, entity_id, entity_type, attr) VALUES "
    if backend == "duckdb":
        con = duckdb.connect(url)
        con.execute(SCHEMA_TABLE)
        for m in old:
            for statement in split_statements(m.sql):
                con.execute(statement)
            con.execute("INSERT INTO schema_migrations (version, name) VALUES (?, ?)", [m.version, m.name])
        con.execute(series + "(1, '', '/', 'e', 'T', 'a'), (2, '', '/', 'e', 'T', 'b')")
        con.executemany("INSERT INTO samples (rid, sid, t, kind, atype, num) VALUES (?, ?, ?, ?, ?, ?)", OLD_ROWS[:2])
        con.executemany(
            "INSERT INTO samples_hot (rid, sid, t, kind, atype, num) VALUES (?, ?, ?, ?, ?, ?)", OLD_ROWS[2:]
        )
        con.close()
        return
    with psycopg.connect(url) as conn:
        conn.execute(SCHEMA_TABLE)
        for m in old:
            conn.execute(m.sql)
            conn.execute("INSERT INTO schema_migrations (version, name) VALUES (%s, %s)", [m.version, m.name])
        conn.execute(series + "(1, '', '/', 'e', 'T', 'a'), (2, '', '/', 'e', 'T', 'b')")
        conn.execute("SELECT setval(pg_get_serial_sequence('series', 'sid'), 2)")
        with conn.cursor() as cur:
            cur.executemany(
                "INSERT INTO samples (rid, sid, t, kind, atype, num) VALUES (%s, %s, %s, %s, %s, %s)", OLD_ROWS
            )


def test_existing_samples_get_instance_ids(store_url, backend):
    _old_store(store_url, backend)
    store = open_store(Settings(db=store_url))
    try:
        q = store.querier()
        refs = q.series(SeriesSelect(Scope(""), EntityFilter(ids=("e",))))
        rows = q.temporal_instances(InstancesRead([r.sid for r in refs]))
        assert sorted(r.num for r in rows) == [1.5, 2.5, 3.5]
        old_ids = {r.iid for r in rows}
        assert len(old_ids) == 3 and None not in old_ids
        assert all(r.observed_at is None and r.dataset_id is None for r in rows)
        store.write_sync(
            [
                AppendSamples(
                    [
                        EntitySample(
                            "",
                            "/",
                            "e",
                            "T",
                            datetime(2024, 2, 1, tzinfo=UTC),
                            [AttrSample("a", "Number", Kind.NUMBER, num=9.0)],
                        )
                    ]
                )
            ]
        )
        new = {r.iid for r in q.temporal_instances(InstancesRead([r.sid for r in refs]))} - old_ids
        assert len(new) == 1 and min(new) > max(old_ids)
    finally:
        store.close()
