"""The ingest log's files: append-only segments of framed records.

A record is one group of accepted notifications (``write.codec`` encodes
them), framed as ``length, crc32, sequence number`` (little-endian u32, u32,
u64) before its payload. A group is written with one ``write`` and made
durable with one ``fdatasync`` before any of its notifications is
acknowledged, so a record on disk is either whole or was never acknowledged:
a crash can only leave a torn *last* record, which ``open`` cuts off.

Segments are named after the first sequence number they hold
(``000000000000000001.seg``) and rotate at ``segment_bytes``. A segment is
deleted once every record in it is applied to the database (``drop_upto``).
Nothing here knows what a record means.
"""

from __future__ import annotations

import os
import struct
import zlib
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

HEADER = struct.Struct("<IIQ")  # payload length, crc32 of the payload, sequence number
SUFFIX = ".seg"
SEGMENT_BYTES = 64 * 1024 * 1024
MAX_RECORD_BYTES = 1 << 31  # a length past this is a torn header, not a record


class LogError(Exception):
    """The log cannot be written (disk full, I/O error): nothing was appended."""


@dataclass(frozen=True, slots=True)
class Segment:
    first_seq: int
    path: Path


class IngestLog:
    """One directory of segments; one appender thread at a time."""

    def __init__(self, directory: str | Path, segment_bytes: int = SEGMENT_BYTES):
        self.directory = Path(directory)
        self.segment_bytes = segment_bytes
        self.directory.mkdir(parents=True, exist_ok=True)
        self._segments: list[Segment] = sorted(
            (Segment(int(p.stem), p) for p in self.directory.glob(f"*{SUFFIX}") if p.stem.isdigit()),
            key=lambda s: s.first_seq,
        )
        self.last_seq = 0
        self._fd: int | None = None
        self._size = 0
        self._recover_tail()

    # -- reading ----------------------------------------------------------------------------

    def records(self, after_seq: int = 0) -> Iterator[tuple[int, bytes]]:
        """Every whole record with a sequence number above ``after_seq``, in order."""
        for segment in list(self._segments):
            for seq, payload, _ in _read(segment.path):
                if seq > after_seq:
                    yield seq, payload

    def _recover_tail(self) -> None:
        """Find the last whole record; cut a torn one off the last segment
        (it was never acknowledged: its fdatasync had not returned)."""
        if not self._segments:
            return
        last = self._segments[-1]
        end = 0
        for seq, _, record_end in _read(last.path):
            self.last_seq, end = seq, record_end
        if self.last_seq == 0:  # an empty or wholly torn segment: its records were never acknowledged
            self.last_seq = last.first_seq - 1
        with open(last.path, "r+b") as f:
            if os.fstat(f.fileno()).st_size != end:
                f.truncate(end)
                os.fsync(f.fileno())

    # -- appending --------------------------------------------------------------------------

    def append(self, payloads: list[bytes]) -> int:
        """Write one record per payload and make them durable; returns the
        last sequence number. Raises ``LogError`` with nothing appended."""
        if not payloads:
            return self.last_seq
        frames = []
        seq = self.last_seq
        for payload in payloads:
            seq += 1
            frames.append(HEADER.pack(len(payload), zlib.crc32(payload), seq))
            frames.append(payload)
        data = b"".join(frames)
        fd = self._writable(self.last_seq + 1, len(data))
        try:
            written = os.write(fd, data)
            while written < len(data):
                written += os.write(fd, data[written:])
            os.fdatasync(fd)
        except OSError as exc:
            self._undo(fd)
            raise LogError(f"the ingest log could not be written: {exc}") from exc
        self._size += len(data)
        self.last_seq = seq
        return seq

    def _writable(self, first_seq: int, incoming: int) -> int:
        """The current segment's descriptor, rotating past ``segment_bytes``."""
        if self._fd is not None and self._size + incoming <= self.segment_bytes:
            return self._fd
        if self._fd is None and self._segments:
            last = self._segments[-1]
            size = last.path.stat().st_size
            if size + incoming <= self.segment_bytes:
                self._fd, self._size = os.open(last.path, os.O_WRONLY | os.O_APPEND), size
                return self._fd
        self.close()
        path = self.directory / f"{first_seq:018d}{SUFFIX}"
        try:
            self._fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT | os.O_EXCL, 0o600)
            _fsync_directory(self.directory)
        except OSError as exc:
            raise LogError(f"the ingest log could not be written: {exc}") from exc
        self._size = 0
        self._segments.append(Segment(first_seq, path))
        return self._fd

    def _undo(self, fd: int) -> None:
        """Cut a failed append off the segment, so the next one starts whole."""
        try:
            os.ftruncate(fd, self._size)
        except OSError:
            self.close()  # the next append reopens the file and finds the tail

    # -- dropping applied records -------------------------------------------------------------

    def drop_upto(self, applied_seq: int) -> int:
        """Delete the segments whose records are all applied (every record up
        to ``applied_seq``); never the one being written. Returns how many."""
        dropped = 0
        while len(self._segments) > 1 and self._segments[1].first_seq <= applied_seq + 1:
            segment = self._segments.pop(0)
            segment.path.unlink(missing_ok=True)
            dropped += 1
        return dropped

    def reset(self) -> None:
        """Delete every segment (all applied); numbering goes on from ``last_seq``."""
        self.close()
        for segment in self._segments:
            segment.path.unlink(missing_ok=True)
        self._segments = []
        _fsync_directory(self.directory)

    def bytes_on_disk(self) -> int:
        return sum(s.path.stat().st_size for s in self._segments if s.path.exists())

    def close(self) -> None:
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None


def _read(path: Path) -> Iterator[tuple[int, bytes, int]]:
    """(seq, payload, end offset) of each whole record of a segment; stops
    at the first torn or corrupt one."""
    data = path.read_bytes()
    offset = 0
    while offset + HEADER.size <= len(data):
        length, crc, seq = HEADER.unpack_from(data, offset)
        start = offset + HEADER.size
        end = start + length
        if length >= MAX_RECORD_BYTES or end > len(data):
            return
        payload = data[start:end]
        if zlib.crc32(payload) != crc:
            return
        yield seq, payload, end
        offset = end


def _fsync_directory(directory: Path) -> None:
    """Make a new segment's directory entry durable."""
    fd = os.open(directory, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)
