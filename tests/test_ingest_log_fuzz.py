"""The ingest log's reader against damaged bytes (``write.log``), fuzzed.

Segments are written by the log itself, then bytes are flipped, the end
cut off, records reordered or duplicated, whole segments dropped. Whatever
the damage: reading never raises (opening a directory raises only
``LogRefused``, which no such damage can cause), never returns a record that
was not written or with another payload, and never one past the damage: what
comes back is always a prefix of what was written. A second opening finds
the log as the first left it.
"""

from __future__ import annotations

import tempfile
import uuid
from pathlib import Path

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tsdb_service.write.log import FRAME, HEADER, IngestLog, frame, header, scan_segment

DB = uuid.uuid4().bytes
FAST = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])

payloads = st.lists(st.binary(min_size=0, max_size=40), min_size=1, max_size=12)


def segment_bytes(first_seq: int, records: list[bytes]) -> bytes:
    return header(DB, first_seq) + b"".join(frame(first_seq + i, p) for i, p in enumerate(records))


def is_prefix(got: list[tuple[int, bytes]], written: list[tuple[int, bytes]]) -> bool:
    return got == written[: len(got)]


@st.composite
def damaged(draw):
    """(written records, the damaged bytes of their segment)."""
    records = draw(payloads)
    data = bytearray(segment_bytes(1, records))
    how = draw(st.sampled_from(["flip", "cut", "reorder", "duplicate", "garbage"]))
    if how == "flip":
        for _ in range(draw(st.integers(1, 3))):
            at = draw(st.integers(0, len(data) - 1))
            data[at] ^= draw(st.integers(1, 255))
    elif how == "cut":
        del data[draw(st.integers(0, len(data))) :]
    elif how in ("reorder", "duplicate"):
        frames = [frame(1 + i, p) for i, p in enumerate(records)]
        if how == "reorder":
            frames = draw(st.permutations(frames))
        else:
            at = draw(st.integers(0, len(frames) - 1))
            frames.insert(at, frames[at])
        data = bytearray(header(DB, 1) + b"".join(frames))
    else:
        at = draw(st.integers(0, len(data)))
        data[at:at] = draw(st.binary(min_size=1, max_size=30))
    return [(1 + i, p) for i, p in enumerate(records)], bytes(data)


@FAST
@given(damaged())
def test_a_damaged_segment_reads_as_a_prefix_of_what_was_written(case):
    written, data = case
    scan = scan_segment(data)
    got = list(scan.payloads(data))
    assert is_prefix(got, written), (got, written)
    assert scan.end <= len(data)
    if scan.damage is None and scan.kind == "current":
        assert scan.end == len(data)


@FAST
@given(st.binary(max_size=300))
def test_any_bytes_read_without_an_exception(data):
    scan = scan_segment(data)
    assert scan.kind in ("current", "legacy", "damaged", "future")
    for seq, payload in scan.payloads(data):
        assert isinstance(seq, int) and isinstance(payload, bytes)


@st.composite
def damaged_directory(draw):
    """Several segments written by the log, then damaged one way."""
    groups = draw(st.lists(payloads, min_size=1, max_size=5))
    how = draw(st.sampled_from(["flip", "cut", "drop", "swap", "empty", "stray"]))
    return groups, how, draw(st.randoms(use_true_random=False))


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(damaged_directory())
def test_a_damaged_log_directory_replays_a_prefix_and_settles(case):
    groups, how, rnd = case
    with tempfile.TemporaryDirectory() as tmp:
        directory = Path(tmp)
        log = IngestLog(directory, DB, segment_bytes=1)  # every append starts a segment
        written: list[tuple[int, bytes]] = []
        for group in groups:
            last = log.append(group)
            written += [(last - len(group) + 1 + i, p) for i, p in enumerate(group)]
        log.close()
        segments = sorted(directory.glob("*.seg"))
        victim = rnd.choice(segments)
        data = bytearray(victim.read_bytes())
        if how == "flip":
            data[rnd.randrange(len(data))] ^= rnd.randrange(1, 256)
            victim.write_bytes(bytes(data))
        elif how == "cut":
            victim.write_bytes(bytes(data[: rnd.randrange(len(data))]))
        elif how == "drop":
            victim.unlink()
        elif how == "swap" and len(segments) > 1:
            other = rnd.choice([s for s in segments if s != victim])
            a, b = victim.read_bytes(), other.read_bytes()
            victim.write_bytes(b)
            other.write_bytes(a)
        elif how == "empty":
            victim.write_bytes(b"")
        elif how == "stray":
            (directory / f"{10**15 + rnd.randrange(1000):018d}.seg").write_bytes(bytes(rnd.randrange(50)))

        opened = IngestLog(directory, DB)
        got = list(opened.records())
        assert is_prefix(got, written), (how, got, written)
        assert opened.last_seq >= (got[-1][0] if got else 0)
        again = IngestLog(directory, DB)  # the first opening left nothing to find
        assert list(again.records()) == got
        assert again.findings.set_aside is None and again.findings.torn_bytes == 0
        assert again.append([b"next"]) == again.last_seq
        assert list(IngestLog(directory, DB).records())[-1][1] == b"next"


def test_frame_and_header_sizes_are_what_the_format_says():
    assert HEADER.size == 40 and FRAME.size == 20
