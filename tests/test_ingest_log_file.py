"""The ingest log's files (``write.log``): whole records survive, a torn tail
is cut off, segments rotate and go once applied, and a record of another
codec version is refused rather than guessed."""

from __future__ import annotations

from datetime import UTC, datetime, timedelta

import pytest

from tests.support.tmpfs import fill, small_tmpfs
from tsdb_service.core.model import AttrSample, EntitySample, Geometry, Kind
from tsdb_service.write import codec
from tsdb_service.write.log import HEADER, IngestLog, LogError
from tsdb_service.write.ops import AppendSamples, Delivery

T0 = datetime(2024, 5, 1, 10, 0, 0, 123456, tzinfo=UTC)


def test_records_read_back_in_order(tmp_path):
    log = IngestLog(tmp_path)
    assert log.append([b"a", b"bb"]) == 2
    assert log.append([b"ccc"]) == 3
    log.close()
    again = IngestLog(tmp_path)
    assert list(again.records()) == [(1, b"a"), (2, b"bb"), (3, b"ccc")]
    assert list(again.records(after_seq=2)) == [(3, b"ccc")]
    assert again.last_seq == 3


@pytest.mark.parametrize("cut", [1, HEADER.size - 1, HEADER.size + 2])
def test_a_torn_last_record_is_cut_and_numbering_goes_on(tmp_path, cut):
    log = IngestLog(tmp_path)
    log.append([b"whole"])
    log.append([b"torn record"])
    log.close()
    [segment] = list(tmp_path.glob("*.seg"))
    size = segment.stat().st_size
    with open(segment, "r+b") as f:
        f.truncate(size - cut)  # the crash came before the fdatasync returned
    again = IngestLog(tmp_path)
    assert list(again.records()) == [(1, b"whole")]
    assert again.append([b"next"]) == 2
    assert list(IngestLog(tmp_path).records()) == [(1, b"whole"), (2, b"next")]


def test_a_corrupt_record_ends_the_segment(tmp_path):
    log = IngestLog(tmp_path)
    log.append([b"one", b"two"])
    log.close()
    [segment] = list(tmp_path.glob("*.seg"))
    data = bytearray(segment.read_bytes())
    data[-1] ^= 0xFF  # the crc no longer matches
    segment.write_bytes(bytes(data))
    assert list(IngestLog(tmp_path).records()) == [(1, b"one")]


def test_segments_rotate_and_go_once_applied(tmp_path):
    log = IngestLog(tmp_path, segment_bytes=64)
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


def test_an_append_on_a_full_disk_leaves_no_record(tmp_path):
    with small_tmpfs(tmp_path / "disk", "1m") as disk:
        log = IngestLog(disk / "log")
        log.append([b"kept"])
        filler = fill(disk, leave=0)
        with pytest.raises(LogError, match="could not be written"):
            log.append([bytes(200_000)])
        filler.unlink()
        assert log.append([b"later"]) == 2
        assert list(IngestLog(disk / "log").records()) == [(1, b"kept"), (2, b"later")]
        log.close()


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


def test_a_record_of_version_1_still_reads():
    """Written before MQTT deliveries: the same layout without them."""
    op = AppendSamples(_entities(), dedup=False)
    old = codec.encode(op).replace(f'"v":{codec.VERSION}'.encode(), b'"v":1')
    assert codec.decode(old) == op


def test_a_record_of_another_version_is_refused():
    payload = codec.encode(AppendSamples(_entities())).replace(f'"v":{codec.VERSION}'.encode(), b'"v":99')
    with pytest.raises(codec.RecordError):
        codec.decode(payload)
