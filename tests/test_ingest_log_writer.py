"""The ingest log's writer (``write.logged``) against a database that is a
Python list: acknowledgement on the log, application in order behind it,
reads that wait for what was acknowledged, the lag bound, replay that
skips what the database holds, and an entity the database refuses."""

from __future__ import annotations

import asyncio
import threading
import time
from datetime import UTC, datetime

import pytest

from tsdb_service.core.errors import Unavailable
from tsdb_service.core.model import AttrSample, EntitySample, Kind
from tsdb_service.write.log import IngestLog
from tsdb_service.write.logged import LoggedWriter
from tsdb_service.write.ops import AppendSamples, LogPosition

T0 = datetime(2024, 5, 1, tzinfo=UTC)
DB = bytes(16)


def synced(w: LoggedWriter, timeout: float = 30.0) -> None:
    """``w.sync()`` once the database takes the log again (it says
    Unavailable while it refuses it)."""
    deadline = time.monotonic() + timeout
    while True:
        try:
            w.sync(timeout=1)
            return
        except Unavailable:
            assert time.monotonic() < deadline, "the log was never applied"
            time.sleep(0.01)


def acknowledge_in_background(w: LoggedWriter, op: AppendSamples) -> None:
    """A request in flight: it returns once the log acknowledged ``op``."""
    threading.Thread(target=asyncio.run, args=(w.write(op),), daemon=True).start()


def entity(n: int, name: str = "speed") -> EntitySample:
    return EntitySample("t", "/", f"e{n}", "T", T0, [AttrSample(name, "Number", Kind.NUMBER, num=float(n))])


class ListDatabase:
    """Holds applied entities and the log position, changed together as a
    transaction would; ``gate`` pauses application; ``refuse`` names entity
    ids it refuses."""

    def __init__(self):
        self.rows: list[tuple[int, str]] = []
        self.rejected: list[str] = []
        self.gate = threading.Event()
        self.gate.set()
        self.refuse: set[str] = set()
        self.next_rid = 1
        self.position = LogPosition(0, 0)

    def apply(self, ops):
        self.gate.wait()
        entities = [e for op in ops for e in op.entities]
        if any(e.entity_id in self.refuse for e in entities):
            raise RuntimeError("refused")
        self.rows += [(e.rid, e.entity_id) for e in entities]
        for op in ops:
            if op.log_position is not None:
                p = op.log_position
                self.position = LogPosition(max(self.position.seq, p.seq), max(self.position.rid, p.rid))

    def allocate(self, n: int) -> int:
        first, self.next_rid = self.next_rid, self.next_rid + n
        return first

    def applied(self) -> LogPosition:
        return self.position

    def writer(self, directory, **kw) -> LoggedWriter:
        w = LoggedWriter(
            IngestLog(directory, DB, applied_seq=self.position.seq),
            self.apply,
            self.allocate,
            self.applied,
            lambda e, reason: self.rejected.append(e.entity_id),
            seen_rid=lambda rid: setattr(self, "next_rid", max(self.next_rid, rid + 1)),
            **kw,
        )
        w.start()
        return w


def test_acknowledged_then_applied_in_order(tmp_path):
    db = ListDatabase()
    w = db.writer(tmp_path)

    async def run():
        await asyncio.gather(*(w.write(AppendSamples([entity(i)])) for i in range(50)))
        await w.caught_up()

    asyncio.run(run())
    assert sorted(db.rows) == db.rows  # row ids grow in log order
    assert sorted(eid for _, eid in db.rows) == sorted(f"e{i}" for i in range(50))
    w.close()


def test_a_read_waits_for_what_was_acknowledged_before_it(tmp_path):
    db = ListDatabase()
    w = db.writer(tmp_path)
    db.gate.clear()  # the database is slow

    async def run():
        await w.write(AppendSamples([entity(1)]))  # acknowledged: durable in the log
        assert db.rows == []
        read = asyncio.ensure_future(w.caught_up())
        await asyncio.sleep(0.05)
        assert not read.done()  # the read waits for it
        db.gate.set()
        await asyncio.wait_for(read, 10)
        assert [eid for _, eid in db.rows] == ["e1"]

    asyncio.run(run())
    w.close()


def test_ingest_waits_past_the_lag_bound_and_reads_do_not(tmp_path):
    db = ListDatabase()
    w = db.writer(tmp_path, max_lag_bytes=1)
    db.gate.clear()

    async def run():
        await w.write(AppendSamples([entity(1)]))  # the first record goes in: the lag was 0
        blocked = asyncio.ensure_future(w.write(AppendSamples([entity(2)])))
        await asyncio.sleep(0.1)
        assert not blocked.done()  # past the bound: ingest waits for the database
        db.gate.set()
        await asyncio.wait_for(blocked, 10)

    asyncio.run(run())
    w.sync()
    assert [eid for _, eid in db.rows] == ["e1", "e2"]
    w.close()


def test_replay_applies_only_what_the_database_lacks(tmp_path):
    db = ListDatabase()
    w = db.writer(tmp_path)
    db.gate.clear()
    for i in range(1, 4):  # one after the other: e1 gets row id 1, e2 2, e3 3
        acknowledge_in_background(w, AppendSamples([entity(i)]))
        while w.acked_seq < i:
            threading.Event().wait(0.01)
    # A crash: the log holds three records, the first database none (its
    # applier stays stuck, as a dead process's would). The next database
    # holds the first, as if it had been applied before the crash.
    w._writer.close()
    again = ListDatabase()
    again.rows = [(1, "e1")]
    again.position = LogPosition(1, 1)
    w2 = again.writer(tmp_path)
    w2.sync()
    assert [eid for _, eid in again.rows] == ["e1", "e2", "e3"]
    assert again.next_rid == 4  # new ids go on above every id the log gave
    w2.close()


def test_an_entity_the_database_always_refuses_is_kept_and_the_rest_goes_on(tmp_path, monkeypatch):
    monkeypatch.setattr("tsdb_service.write.logged.RETRY_DELAY_S", 0.001)
    db = ListDatabase()
    db.refuse = {"e2"}
    w = db.writer(tmp_path)
    db.gate.clear()
    for i in (1, 2, 3):
        acknowledge_in_background(w, AppendSamples([entity(i)]))
    while w.acked_seq < 3:
        threading.Event().wait(0.01)
    db.gate.set()
    synced(w)
    assert sorted(eid for _, eid in db.rows) == ["e1", "e3"]
    assert db.rejected == ["e2"]
    w.close()


def test_a_sick_database_never_sends_entities_to_the_rejected_store(tmp_path, monkeypatch):
    monkeypatch.setattr("tsdb_service.write.logged.RETRY_DELAY_S", 0.001)
    monkeypatch.setattr("tsdb_service.write.logged.RETRY_MAX_DELAY_S", 0.002)
    db = ListDatabase()
    db.refuse = {"e1"}
    w = LoggedWriter(
        IngestLog(tmp_path, DB), db.apply, db.allocate, db.applied, lambda e, r: db.rejected.append(e.entity_id),
        healthy=lambda: False,
    )  # fmt: skip
    w.start()
    acknowledge_in_background(w, AppendSamples([entity(1)]))
    threading.Event().wait(0.3)
    assert db.rejected == [] and db.rows == []
    assert w.failure is not None and "retrying" in w.failure
    with pytest.raises(Unavailable):  # a read cannot see what was acknowledged: 503, not a wait
        asyncio.run(w.caught_up())
    db.refuse = set()  # space is back
    synced(w)
    assert [eid for _, eid in db.rows] == ["e1"]
    assert w.failure is None
    w.close()


def test_replay_honours_what_the_database_deleted(tmp_path):
    """The rows of applied records may be gone (a delete, retention): the
    position the database keeps, not its largest row id, says they were applied."""
    db = ListDatabase()
    w = db.writer(tmp_path)
    for i in (1, 2):
        asyncio.run(w.write(AppendSamples([entity(i)])))
    w.sync()
    db.rows = [row for row in db.rows if row[1] != "e2"]  # the newest entity deleted
    w.close()  # a clean stop: the log keeps its last segment
    w2 = db.writer(tmp_path)
    w2.sync()
    assert [eid for _, eid in db.rows] == ["e1"]
    asyncio.run(w2.write(AppendSamples([entity(3)])))
    w2.sync()
    assert [eid for _, eid in db.rows] == ["e1", "e3"]
    assert db.rows[-1][0] > 2  # row ids never reused
    w2.close()


def test_a_commit_that_landed_but_said_it_failed_is_not_applied_twice(tmp_path, monkeypatch):
    monkeypatch.setattr("tsdb_service.write.logged.RETRY_DELAY_S", 0.001)
    db = ListDatabase()
    landed_once = []

    def apply_then_fail(ops):
        db.apply(ops)
        if not landed_once:
            landed_once.append(True)
            raise RuntimeError("the connection broke during COMMIT")

    w = LoggedWriter(IngestLog(tmp_path, DB), apply_then_fail, db.allocate, db.applied, lambda e, r: None)
    w.start()
    asyncio.run(w.write(AppendSamples([entity(1), entity(2)])))
    synced(w)
    assert [eid for _, eid in db.rows] == ["e1", "e2"]
    w.close()


def test_entities_applied_one_by_one_before_a_crash_are_not_applied_again(tmp_path, monkeypatch):
    monkeypatch.setattr("tsdb_service.write.logged.RETRY_DELAY_S", 0.001)
    db = ListDatabase()
    db.refuse = {"e2"}
    w = db.writer(tmp_path)
    asyncio.run(w.write(AppendSamples([entity(1), entity(2), entity(3)])))
    synced(w)
    assert sorted(eid for _, eid in db.rows) == ["e1", "e3"] and db.rejected == ["e2"]
    w.close()
    # As if the process died after the single applies, before the final position:
    db.position = LogPosition(0, db.position.rid)
    again = db.writer(tmp_path)
    again.sync()
    assert sorted(eid for _, eid in db.rows) == ["e1", "e3"]  # none twice
    again.close()


def test_records_the_database_holds_wholly_still_move_the_position(tmp_path):
    """A replayed record whose every entity the database holds must not
    leave reads waiting for it."""
    db = ListDatabase()
    w = db.writer(tmp_path)
    db.gate.clear()
    acknowledge_in_background(w, AppendSamples([entity(1)]))
    while w.acked_seq < 1:
        threading.Event().wait(0.01)
    w._writer.close()
    again = ListDatabase()
    again.rows = [(1, "e1")]
    again.position = LogPosition(0, 1)  # its entity applied alone, the record not marked
    w2 = again.writer(tmp_path)
    w2.sync(timeout=10)
    assert w2.applied_seq == w2.acked_seq == 1 and again.rows == [(1, "e1")]
    w2.close()
