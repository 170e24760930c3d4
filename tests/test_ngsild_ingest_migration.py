"""Migration 0005 on a store with data from before it: every existing
sample gets a unique instance id, reads keep working, new samples get new ids."""

from __future__ import annotations

from datetime import UTC, datetime

from tests.support.old_store import old_store
from tsdb_service.core.config import Settings
from tsdb_service.core.model import AttrSample, EntitySample, Kind
from tsdb_service.core.query import EntityFilter, Scope
from tsdb_service.read.requests import InstancesRead, SeriesSelect
from tsdb_service.storage import open_store
from tsdb_service.write.ops import AppendSamples

OLD_ROWS = [
    (1, 1, "2024-01-01 00:00:00", 1, "Number", 1.5),
    (1, 2, "2024-01-01 00:00:00", 1, "Number", 2.5),
    (2, 1, "2024-01-02 00:00:00", 1, "Number", 3.5),
]


def _old_store(url: str, backend: str) -> None:
    """A store migrated up to 0004, with samples in it (on DuckDB the last one hot)."""
    insert = "INSERT INTO {table} (rid, sid, t, kind, atype, num) VALUES ({{p}}, {{p}}, {{p}}, {{p}}, {{p}}, {{p}})"
    hot = "samples_hot" if backend == "duckdb" else "samples"
    rows = [
        *((insert.format(table="samples"), list(r)) for r in OLD_ROWS[:2]),
        *((insert.format(table=hot), list(r)) for r in OLD_ROWS[2:]),
    ]
    old_store(url, backend, 5, rows, attrs=("a", "b"))


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
