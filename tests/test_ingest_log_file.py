"""The ingest log's files (``write.log``): whole records survive, a torn tail
is cut off without a word, damage is set aside with everything after it,
segments rotate and go once applied, a log of another database (or of no
known one) is refused, and a record of another codec version is refused
rather than guessed."""

from __future__ import annotations

import struct
import uuid
import zlib
from dataclasses import fields
from datetime import UTC, datetime, timedelta

import orjson
import pytest

from tests.support.tmpfs import fill, small_tmpfs
from tsdb_service.core.model import AttrSample, EntitySample, Geometry, Kind
from tsdb_service.write import codec
from tsdb_service.write.log import FRAME, HEADER, QUARANTINE, IngestLog, LogError, LogRefused
from tsdb_service.write.ops import AppendSamples, Delivery

T0 = datetime(2024, 5, 1, 10, 0, 0, 123456, tzinfo=UTC)
DB = uuid.uuid4().bytes


def opened(directory, **kw) -> IngestLog:
    return IngestLog(directory, DB, **kw)


def test_records_read_back_in_order(tmp_path):
    log = opened(tmp_path)
    assert log.append([b"a", b"bb"]) == 2
    assert log.append([b"ccc"]) == 3
    log.close()
    again = opened(tmp_path)
    assert list(again.records()) == [(1, b"a"), (2, b"bb"), (3, b"ccc")]
    assert list(again.records(after_seq=2)) == [(3, b"ccc")]
    assert again.last_seq == 3
    assert again.findings.set_aside is None and again.findings.torn_bytes == 0


@pytest.mark.parametrize("cut", [1, FRAME.size - 1, FRAME.size + 2])
def test_a_torn_last_record_is_cut_and_numbering_goes_on(tmp_path, cut):
    log = opened(tmp_path)
    log.append([b"whole"])
    log.append([b"torn record"])
    log.close()
    [segment] = list(tmp_path.glob("*.seg"))
    size = segment.stat().st_size
    with open(segment, "r+b") as f:
        f.truncate(size - cut)  # the crash came before the fdatasync returned
    again = opened(tmp_path)
    assert list(again.records()) == [(1, b"whole")]
    assert again.findings.torn_bytes == FRAME.size + len(b"torn record") - cut
    assert again.findings.set_aside is None
    assert again.append([b"next"]) == 2
    assert list(opened(tmp_path).records()) == [(1, b"whole"), (2, b"next")]


def test_a_flipped_byte_in_the_last_record_cannot_be_told_from_a_tear(tmp_path):
    log = opened(tmp_path)
    log.append([b"one"])
    log.append([b"two"])
    log.close()
    [segment] = list(tmp_path.glob("*.seg"))
    data = bytearray(segment.read_bytes())
    data[-1] ^= 0xFF
    segment.write_bytes(bytes(data))
    again = opened(tmp_path)
    assert list(again.records()) == [(1, b"one")]
    assert again.findings.set_aside is None  # it may have been torn: never acknowledged


def test_a_damaged_record_with_records_after_it_is_set_aside_with_them(tmp_path):
    log = opened(tmp_path)
    log.append([b"one", b"two", b"three", b"four"])
    log.close()
    [segment] = list(tmp_path.glob("*.seg"))
    data = bytearray(segment.read_bytes())
    data[data.find(b"two")] ^= 0x01
    segment.write_bytes(bytes(data))
    again = opened(tmp_path)
    assert list(again.records()) == [(1, b"one")]
    found = again.findings.set_aside
    assert found is not None and found.records == 3 and found.first_seq == 2 and found.later_segments == 0
    assert found.offset == HEADER.size + FRAME.size + len(b"one")
    [tail] = list((tmp_path / QUARANTINE).rglob("*.from-*"))
    assert tail.read_bytes() == bytes(data[found.offset :])
    assert again.quarantined()
    assert again.append([b"five"]) == 2  # numbering goes on after what is kept
    assert list(opened(tmp_path).records()) == [(1, b"one"), (2, b"five")]


def test_segments_rotate_and_go_once_applied(tmp_path):
    log = opened(tmp_path, segment_bytes=128)
    for i in range(10):
        log.append([bytes(30) + bytes([i])])
    segments = sorted(tmp_path.glob("*.seg"))
    assert len(segments) > 3
    assert log.drop_upto(4) >= 1
    assert all(seq > 4 for seq, _ in log.records(after_seq=4))
    assert [seq for seq, _ in log.records()][-1] == 10
    assert log.drop_upto(10) >= 1
    assert len(list(tmp_path.glob("*.seg"))) == 1  # never the one being written
    log.reset()
    assert list(tmp_path.glob("*.seg")) == []
    assert log.append([b"after"]) == 11


def test_numbering_goes_on_above_what_the_database_holds(tmp_path):
    """A log that lost its files (reset, or deleted by hand) must never
    number new records at or below the database's position: a replay
    would skip them."""
    log = opened(tmp_path, applied_seq=41)
    assert log.last_seq == 41
    assert log.append([b"x"]) == 42
    log.close()
    assert list(opened(tmp_path, applied_seq=41).records(after_seq=41)) == [(42, b"x")]


def test_a_segment_that_does_not_follow_is_set_aside_unless_the_database_holds_the_gap(tmp_path):
    log = opened(tmp_path, segment_bytes=64)
    for i in range(6):
        log.append([bytes(40) + bytes([i])])
    log.close()
    segments = sorted(tmp_path.glob("*.seg"))
    assert len(segments) == 6
    segments[2].unlink()  # records 3 is missing: never replay 4 on
    again = opened(tmp_path)
    assert [seq for seq, _ in again.records()] == [1, 2]
    assert again.findings.set_aside is not None and "missing" in again.findings.set_aside.reason
    again.close()
    other = tmp_path / "other"
    log = IngestLog(other, DB, segment_bytes=64)
    for i in range(4):
        log.append([bytes(40) + bytes([i])])
    log.close()
    sorted(other.glob("*.seg"))[1].unlink()  # record 2 is gone, but the database holds it
    held = IngestLog(other, DB, applied_seq=2)
    assert [seq for seq, _ in held.records(after_seq=2)] == [3, 4] and held.findings.set_aside is None


def test_another_databases_log_is_refused_and_left_as_it_is(tmp_path):
    log = opened(tmp_path)
    log.append([b"theirs"])
    log.close()
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    with pytest.raises(LogRefused, match="another database"):
        IngestLog(tmp_path, uuid.uuid4().bytes)
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == before


def test_a_log_of_a_newer_format_is_refused(tmp_path):
    log = opened(tmp_path)
    log.append([b"x"])
    log.close()
    [segment] = list(tmp_path.glob("*.seg"))
    data = bytearray(segment.read_bytes())
    head = bytearray(data[: HEADER.size - 4])
    head[8:10] = struct.pack("<H", 3)
    data[: HEADER.size] = head + struct.pack("<I", zlib.crc32(head))
    segment.write_bytes(bytes(data))
    with pytest.raises(LogRefused, match="newer"):
        opened(tmp_path)


def legacy_segment(directory, first_seq: int, payloads: list[bytes]) -> None:
    """A segment as tsdb-service wrote them before they had a header."""
    frames = b"".join(struct.pack("<IIQ", len(p), zlib.crc32(p), first_seq + i) + p for i, p in enumerate(payloads))
    (directory / f"{first_seq:018d}.seg").write_bytes(frames)


def test_a_log_from_before_headers_is_replayed_once_after_the_upgrade_then_refused(tmp_path):
    legacy_segment(tmp_path, 1, [b"a", b"b"])
    legacy_segment(tmp_path, 3, [b"c"])
    log = opened(tmp_path, accept_legacy=True)
    assert list(log.records()) == [(1, b"a"), (2, b"b"), (3, b"c")]
    assert log.has_legacy() and log.findings.legacy_segments == 2
    assert log.append([b"d"]) == 4  # in a segment of the current format
    log.close()
    assert list(opened(tmp_path, accept_legacy=True).records()) == [(1, b"a"), (2, b"b"), (3, b"c"), (4, b"d")]
    with pytest.raises(LogRefused, match="without a database identity"):
        opened(tmp_path)


def test_stray_files_are_ignored_and_said_an_unfinished_segment_is_deleted(tmp_path, caplog):
    log = opened(tmp_path)
    log.append([b"a"])
    log.close()
    (tmp_path / "README").write_text("notes")
    (tmp_path / f"{7:018d}.seg.tmp").write_bytes(b"half a segment")
    with caplog.at_level("WARNING"):
        again = opened(tmp_path)
    assert list(again.records()) == [(1, b"a")]
    assert again.findings.ignored == ["README"] and "README" in caplog.text
    assert not (tmp_path / f"{7:018d}.seg.tmp").exists()


def test_an_append_on_a_full_disk_leaves_no_record(tmp_path):
    with small_tmpfs(tmp_path / "disk", "1m") as disk:
        log = opened(disk / "log")
        log.append([b"kept"])
        filler = fill(disk, leave=0)
        with pytest.raises(LogError, match="could not be written"):
            log.append([bytes(200_000)])
        filler.unlink()
        assert log.append([b"later"]) == 2
        assert list(opened(disk / "log").records()) == [(1, b"kept"), (2, b"later")]
        log.close()


def test_a_new_segment_on_a_full_disk_leaves_nothing_behind(tmp_path):
    with small_tmpfs(tmp_path / "disk", "1m") as disk:
        log = opened(disk / "log")
        filler = fill(disk, leave=0)
        with pytest.raises(LogError, match="could not be written"):
            log.append([bytes(200_000)])
        assert list((disk / "log").iterdir()) == []
        filler.unlink()
        assert log.append([b"later"]) == 1
        log.close()
        assert list(opened(disk / "log").records()) == [(1, b"later")]


def _entities() -> list[EntitySample]:
    point = Geometry('{"type":"Point","coordinates":[1.5,2.25]}', 1.5, 2.25, 1.5, 2.25, 1.5, 2.25)
    return [
        EntitySample(
            "acme",
            "/garden",
            "Robot:1",
            "Robot",
            T0,
            [
                AttrSample("speed", "Number", Kind.NUMBER, num=0.1),
                AttrSample("count", "Integer", Kind.INTEGER, num=3.0),
                AttrSample("name", "Text", Kind.TEXT, txt="ünïcode ✓"),
                AttrSample("where", "geo:json", Kind.GEO, js='{"type":"Point"}', geo=point),
                AttrSample(
                    "temp~sensor2",
                    "Property",
                    Kind.NUMBER,
                    num=-1e-300,
                    md='{"unitCode":"CEL"}',
                    observed_at=T0 - timedelta(microseconds=1),
                    created_at=T0,
                    dataset_id="sensor2",
                ),
                AttrSample("gone", None, Kind.NULL, deleted_at=T0),
            ],
            deleted_at=None,
            rid=42,
        ),
        EntitySample("", "/", "e", "T", T0, [], deleted_at=T0, rid=43),
    ]


def test_the_codec_round_trips_every_field():
    op = AppendSamples(_entities(), dedup=False)
    back = codec.decode(codec.encode(op))
    assert back == op


def test_the_codec_round_trips_mqtt_deliveries():
    deliveries = (
        Delivery("tsdb-a", 7, 65535, bytes(range(16)), T0, prune_below=0),
        Delivery("tsdb-a", 8, 1, b"\xff" * 16, T0 + timedelta(microseconds=1), prune_below=3),
    )
    op = AppendSamples(_entities(), deliveries=deliveries)
    assert codec.decode(codec.encode(op)) == op


def _as_objects(op: AppendSamples, version: int) -> bytes:
    """A record as versions 1 and 2 wrote it: the dataclasses as objects (orjson's own layout)."""
    doc: dict = {"v": version, "dedup": op.dedup, "entities": op.entities}
    if op.deliveries:
        doc["deliveries"] = [
            (d.client_id, d.seq, d.packet_id, d.digest.hex(), d.received_at, d.prune_below) for d in op.deliveries
        ]
    return orjson.dumps(doc)


def test_a_record_of_version_1_still_reads():
    """Written before MQTT deliveries: version 2's layout without them."""
    op = AppendSamples(_entities(), dedup=False)
    assert codec.decode(_as_objects(op, 1)) == op


def test_a_record_of_version_2_still_reads():
    """Entities and attributes as objects, deliveries included."""
    deliveries = (Delivery("tsdb-a", 7, 65535, bytes(range(16)), T0, prune_below=2),)
    op = AppendSamples(_entities(), deliveries=deliveries)
    assert codec.decode(_as_objects(op, 2)) == op


def test_the_codec_layout_names_every_field_of_the_model():
    """A field added to the model must be added to the record's arrays (and VERSION moved)."""
    assert tuple(f.name for f in fields(EntitySample)) == codec.ENTITY_FIELDS
    assert tuple(f.name for f in fields(AttrSample)) == codec.ATTR_FIELDS + codec.LD_FIELDS
    assert tuple(f.name for f in fields(Geometry)) == (
        "geojson",
        "lon",
        "lat",
        "min_lon",
        "min_lat",
        "max_lon",
        "max_lat",
    )


def test_an_ngsiv2_attribute_is_written_without_the_ngsi_ld_fields():
    op = AppendSamples([EntitySample("", "/", "e", "T", T0, [AttrSample("v", "Number", Kind.NUMBER, num=1.0)], rid=1)])
    record = orjson.loads(codec.encode(op))
    assert record["entities"][0][5] == [["v", "Number", 1, 1.0, None, None, None, None]]
    assert codec.decode(codec.encode(op)) == op


def test_a_record_of_another_version_is_refused():
    payload = codec.encode(AppendSamples(_entities())).replace(f'"v":{codec.VERSION}'.encode(), b'"v":99')
    with pytest.raises(codec.RecordError):
        codec.decode(payload)
