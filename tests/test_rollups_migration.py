"""Migration 0014 on a store from before it: every stored sample is rolled
up into both levels, the hours retention folded into ``rollups_hourly``
(whose raw samples are gone) are carried into the hour level, combined with
what raw is left of a split hour, and the old table goes."""

from __future__ import annotations

from datetime import datetime

from tests.support.old_store import old_store
from tests.support.rollups import differences
from tsdb_service.core.config import Settings
from tsdb_service.core.query import AggBranch, Aggregation, AggrMethod, AggrPeriod, TimeRange
from tsdb_service.read.requests import AggregateRead
from tsdb_service.storage import open_store

RAW = [  # rid, sid, t, kind, num: the 10:00 hour is split, its start folded by retention
    (1, 1, "2024-01-01 10:35:00", 2, 5.0),
    (2, 1, "2024-01-01 10:50:30", 2, 7.0),
    (3, 1, "2024-01-01 11:02:00", 1, 0.5),
    (4, 2, "2024-01-01 11:02:00", 4, None),
]
FOLDED = [  # sid, hour, n_present, n_numeric, sum, min, max, all_integer
    (1, "2024-01-01 09:00:00", 4, 4, 10.0, 1.0, 4.0, True),
    (1, "2024-01-01 10:00:00", 2, 2, 3.0, 1.0, 2.0, True),
    (2, "2024-01-01 09:00:00", 3, 0, None, None, None, None),
]


def _old_store(url: str, backend: str) -> None:
    """A store migrated up to 0013, with raw samples, folded hours and watermarks."""
    rows = [
        *(
            (
                "INSERT INTO samples (rid, sid, t, kind, num) VALUES ({p}, {p}, CAST({p} AS TIMESTAMP), {p}, {p})",
                list(r),
            )
            for r in RAW
        ),
        *(
            ("INSERT INTO rollups_hourly VALUES ({p}, CAST({p} AS TIMESTAMP), {p}, {p}, {p}, {p}, {p}, {p})", list(f))
            for f in FOLDED
        ),
        ("INSERT INTO retention_state VALUES ('rollups', '*', TIMESTAMP '2023-01-01', TIMESTAMP '2024-01-02')", []),
        (
            "INSERT INTO retention_state VALUES ('samples', '*', TIMESTAMP '2024-01-01 10:35', TIMESTAMP '2024-01-02')",
            [],
        ),
    ]
    old_store(url, backend, 14, rows, attrs=("a", "b"))


def test_old_rollups_are_carried_and_every_sample_rolled_up(store_url, backend):
    _old_store(store_url, backend)
    store = open_store(Settings(db=store_url))
    try:
        q = store.querier()
        hours = q._fetch(
            "SELECT sid, bucket, sum(n_present), sum(n_numeric), sum(n_integer), sum(num_sum), min(num_min), "
            "max(num_max) FROM rollups_hour_all GROUP BY sid, bucket ORDER BY sid, bucket",
            [],
        )
        at = lambda h: datetime(2024, 1, 1, h)  # noqa: E731
        assert [tuple(int(v) if i in (2, 3, 4) else v for i, v in enumerate(row)) for row in hours] == [
            (1, at(9), 4, 4, 4, 10.0, 1.0, 4.0),
            (1, at(10), 4, 4, 4, 15.0, 1.0, 7.0),  # folded + raw of the split hour
            (1, at(11), 1, 1, 0, 0.5, 0.5, 0.5),
            (2, at(9), 3, 0, 0, None, None, None),
            (2, at(11), 1, 0, 0, None, None, None),
        ]
        minutes = q._fetch("SELECT sid, bucket FROM rollups_minute_all ORDER BY sid, bucket", [])
        assert minutes == [
            (1, at(10).replace(minute=35)),
            (1, at(10).replace(minute=50)),
            (1, at(11).replace(minute=2)),
            (2, at(11).replace(minute=2)),
        ]
        expired = q._fetch("SELECT sid, upto FROM rollups_expired ORDER BY sid", [])
        assert [(sid, upto.replace(microsecond=0)) for sid, upto in expired] == [
            (1, at(10).replace(minute=59, second=59)),
            (2, at(9).replace(minute=59, second=59)),
        ]
        tables = q._fetch("SELECT count(*) FROM information_schema.tables WHERE table_name = 'rollups_hourly'", [])
        assert tables == [(0,)]
        assert sorted(q._fetch("SELECT tbl, rule FROM retention_state", [])) == [("hour", "*"), ("samples", "*")]
        rows = q.aggregate(AggregateRead([AggBranch((1,))], TimeRange(), Aggregation(AggrMethod.SUM, AggrPeriod.DAY)))
        assert [(r.n_present, r.value) for r in rows] == [(9, 25.5)]  # 6 folded + 3 raw
        assert [d for d in differences(store) if d[2] != at(9) and d[2].hour != 10] == []  # raw hours equal raw
    finally:
        store.close()
