"""A DuckDB store upgraded from before its ingest log had headers (migration
0013): the log it left is applied once, what it had applied is not applied
again, and once that log is gone a segment without identity is refused.

The store is made as that version left it: samples applied, its
``store_state`` not there yet, and a log of headerless segments whose first
records the database holds (their row ids are at or below its largest) and
whose last ones it lacks.
"""

from __future__ import annotations

import struct
import zlib

import duckdb
import pytest

from tests.support.ingest_log import leave_unapplied, log_dir, readings
from tsdb_service.core.config import Settings
from tsdb_service.storage import StoreUnavailable, open_store
from tsdb_service.write import codec

TENANT = "upgraded"


def legacy_segment(directory, first_seq: int, payloads: list[bytes]) -> None:
    frames = b"".join(struct.pack("<IIQ", len(p), zlib.crc32(p), first_seq + i) + p for i, p in enumerate(payloads))
    (directory / f"{first_seq:018d}.seg").write_bytes(frames)


def levels(db) -> list[float]:
    con = duckdb.connect(str(db), read_only=True)
    try:
        return [
            r[0]
            for r in con.execute(
                "SELECT a.num FROM series s JOIN samples_all a ON a.sid = s.sid WHERE s.tenant = ? ORDER BY a.t",
                [TENANT],
            ).fetchall()
        ]
    finally:
        con.close()


def test_an_old_log_is_applied_once_after_the_upgrade_and_then_refused(tmp_path):
    db = tmp_path / "old.duckdb"
    leave_unapplied(db, [readings(TENANT, "Tank:1", [0, 1, 2])])
    open_store(Settings(db=str(db))).close()  # applied: rows 1 to 3
    con = duckdb.connect(str(db))
    con.execute("DROP TABLE store_state")
    con.execute("DELETE FROM schema_migrations WHERE version = 13")
    con.close()
    assert levels(db) == [0.25, 1.25, 2.25]

    # The log that version left: records of rows 2 and 3 (applied) and 4, 5 (not).
    old = []
    for rid, value in ((2, 1), (3, 2), (4, 3), (5, 4)):
        op = readings(TENANT, "Tank:1", [value])
        op.entities[0].rid = rid
        old.append(codec.encode(op))
    log_dir(db).mkdir(exist_ok=True)
    for segment in log_dir(db).glob("*.seg"):
        segment.unlink()
    legacy_segment(log_dir(db), 7, old[:2])
    legacy_segment(log_dir(db), 9, old[2:])

    store = open_store(Settings(db=str(db)))
    store.sync()
    store.close()
    assert levels(db) == [0.25, 1.25, 2.25, 3.25, 4.25]  # 3.25 and 4.25 once; none of the others twice

    open_store(Settings(db=str(db))).close()  # the old segments are all applied: they go
    assert not any(log_dir(db).glob("*.seg"))
    assert levels(db) == [0.25, 1.25, 2.25, 3.25, 4.25]

    legacy_segment(log_dir(db), 11, old[2:])  # a headerless log appearing now: not this database's, maybe
    with pytest.raises(StoreUnavailable, match="without a database identity"):
        open_store(Settings(db=str(db)))
    assert levels(db) == [0.25, 1.25, 2.25, 3.25, 4.25]
