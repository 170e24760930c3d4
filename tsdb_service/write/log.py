"""The ingest log's files: identified segments of checksummed records.

Invariants:

* **A segment is whole from its creation.** It is written under a temporary
  name with its header and its first group of records, made durable, and
  only then renamed into place; so a segment always starts with a valid
  header and at least one record, and a crash during its creation leaves
  only a ``.seg.tmp`` file (never acknowledged, deleted at the next start).
* **A record is acknowledged only once durable.** A group of records is
  written with one ``write`` and one ``fdatasync`` before any of its
  notifications is acknowledged, so a crash can leave only a torn end of
  the last segment's last write: cut off at start, without a word.
* **Every record says where it belongs.** A segment's header names the
  database it belongs to (its id), the log format and the sequence number
  of its first record; each record carries its sequence number, and a
  crc32 over its length, sequence number and payload. Records follow each
  other by one, across segments too; a gap is allowed only where the
  database holds every missing record (``applied_seq``).
* **Nothing past damage is replayed.** The first record that fails its
  checks and is not a torn end (something whole follows it, or it starts a
  segment), a segment whose header is damaged or missing, or a gap the
  database does not cover, ends the log: the rest of that segment and every
  later segment are moved into ``quarantine/`` for an operator to inspect,
  one error line says where and how much, and ``findings`` keeps it.
* **Another database's log is never replayed.** A segment naming another
  database, or written by a newer version, makes ``IngestLog`` refuse to
  open (``LogRefused``) before anything is changed.

Segments are named after their first sequence number
(``000000000000000001.seg``), rotate at ``segment_bytes`` and are deleted
once every record in them is applied (``drop_upto``). Appends after a start
always begin a new segment. Segments written before the header existed
(format 1: no header, a crc32 of the payload only) are read when
``accept_legacy`` says the database may still hold such a log (the first
start after the upgrade), and refused otherwise: they carry no identity.
Nothing here knows what a record means.
"""

from __future__ import annotations

import contextlib
import logging
import os
import re
import struct
import zlib
from collections.abc import Iterator
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path

log = logging.getLogger(__name__)

MAGIC = b"\x89TSDBLOG"
FORMAT = 2
# magic, format, reserved, database id, first sequence number, crc32 of the bytes before it
HEADER = struct.Struct("<8sHH16sQI")
MARK = b"\xffLR\xfe"  # starts every record; never in UTF-8 text (the payloads are JSON)
# mark, payload length, sequence number, crc32 of (length, sequence number, payload)
FRAME = struct.Struct("<4sIQI")
_CHECKED = struct.Struct("<IQ")  # the part of FRAME the crc covers, before the payload
LEGACY_FRAME = struct.Struct("<IIQ")  # format 1: payload length, crc32 of the payload, sequence number
SUFFIX = ".seg"
TMP_SUFFIX = ".seg.tmp"
QUARANTINE = "quarantine"
SEGMENT_BYTES = 64 * 1024 * 1024
MAX_RECORD_BYTES = 1 << 31  # a length past this is damage, not a record
_SEGMENT_NAME = re.compile(r"^\d{18}\.seg$")


class LogError(Exception):
    """The log cannot be written (disk full, I/O error, a directory that is
    not writable): nothing was appended."""


class LogRefused(Exception):
    """The directory holds a log this database must not replay (another
    database's, a newer version's, or one without identity); nothing was
    changed. The message says what to do."""


@dataclass(frozen=True, slots=True)
class Segment:
    first_seq: int
    path: Path
    legacy: bool = False


@dataclass(frozen=True, slots=True)
class SetAside:
    """Damage found at start, and what was moved into the quarantine."""

    segment: str  # the segment's file name
    offset: int  # where its damage begins
    reason: str
    first_seq: int  # the sequence number the damaged record had (or should have had)
    records: int  # records set aside: the damaged one and every whole one after it
    bytes: int
    later_segments: int
    folder: Path


@dataclass(slots=True)
class Findings:
    """What opening the log found besides its records."""

    torn_bytes: int = 0  # a torn last write, cut off
    set_aside: SetAside | None = None
    ignored: list[str] = field(default_factory=list)  # files in the directory that are not segments
    legacy_segments: int = 0  # segments of format 1 still to replay


@dataclass(frozen=True, slots=True)
class Scan:
    """One segment read through: where its whole records are, and why it
    stops before its end (``damage``; None: clean to the end)."""

    kind: str  # "current", "legacy", "damaged" (no valid header) or "future" (a newer format)
    database_id: bytes | None
    first_seq: int | None
    records: list[tuple[int, int, int]]  # (sequence number, payload start, payload end)
    end: int  # the offset after the last whole record
    damage: str | None
    after: int  # whole records found past the damage

    def payloads(self, data: bytes) -> Iterator[tuple[int, bytes]]:
        for seq, start, end in self.records:
            yield seq, data[start:end]


def scan_segment(data: bytes, named: int | None = None) -> Scan:
    """Read one segment's bytes: its header, its whole records in order,
    and where and why it stops. ``named``: the first sequence number its
    file name says (a segment of format 1 must start there). Never raises;
    never returns a record that fails its checks or does not follow the one
    before it."""
    if data.startswith(MAGIC):
        if len(data) < HEADER.size:
            return Scan("damaged", None, None, [], 0, "a torn header", 0)
        _, version, _, database_id, first_seq, crc = HEADER.unpack_from(data)
        if zlib.crc32(data[: HEADER.size - 4]) != crc:
            return Scan("damaged", None, None, [], 0, "its header fails its checksum", _whole_after(data, 0))
        if version != FORMAT:
            return Scan("future" if version > FORMAT else "damaged", database_id, first_seq, [], 0, None, 0)
        return _records(data, database_id, first_seq)
    legacy = _legacy_records(data)
    if legacy.records and (named is None or legacy.first_seq == named):
        return legacy
    reason = "it is empty" if not data else "it has no valid header"
    return Scan("damaged", None, None, [], 0, reason, _whole_after(data, 0))


def _records(data: bytes, database_id: bytes, first_seq: int) -> Scan:
    records: list[tuple[int, int, int]] = []
    offset, expected = HEADER.size, first_seq
    damage = None
    while offset < len(data):
        frame = _frame_at(data, offset)
        if isinstance(frame, str):
            damage = frame
            break
        seq, start, end = frame
        if seq != expected:
            damage = f"its record has sequence number {seq} where {expected} was due"
            break
        records.append((seq, start, end))
        offset, expected = end, expected + 1
    after = _whole_after(data, offset + 1) if damage else 0
    return Scan("current", database_id, first_seq, records, offset, damage, after)


def _frame_at(data: bytes, offset: int) -> tuple[int, int, int] | str:
    """(seq, payload start, payload end) of the record at ``offset``, or why
    there is none."""
    if offset + FRAME.size > len(data):
        return "a torn record header"
    mark, length, seq, crc = FRAME.unpack_from(data, offset)
    if mark != MARK:
        return "no record starts there"
    start = offset + FRAME.size
    end = start + length
    if length >= MAX_RECORD_BYTES or end > len(data):
        return "a record runs past the end of the segment"
    if zlib.crc32(memoryview(data)[start:end], zlib.crc32(_CHECKED.pack(length, seq))) != crc:
        return "a record fails its checksum"
    return seq, start, end


def _whole_after(data: bytes, start: int) -> int:
    """How many whole records (of the current format) start at or after ``start``."""
    count = 0
    at = data.find(MARK, start)
    while at >= 0:
        frame = _frame_at(data, at)
        if isinstance(frame, str):
            at = data.find(MARK, at + 1)
        else:
            count += 1
            at = data.find(MARK, frame[2])
    return count


def _legacy_records(data: bytes) -> Scan:
    """A format-1 segment: records from offset 0, stopping at the first
    torn or damaged one (format 1 cannot tell a tear from damage)."""
    records: list[tuple[int, int, int]] = []
    offset, expected = 0, None
    damage = None
    while offset < len(data):
        if offset + LEGACY_FRAME.size > len(data):
            damage = "a torn record header"
            break
        length, crc, seq = LEGACY_FRAME.unpack_from(data, offset)
        start = offset + LEGACY_FRAME.size
        end = start + length
        if not 0 < length < MAX_RECORD_BYTES or seq < 1 or end > len(data):  # records were never empty
            damage = "a record is torn or fails its checksum"
            break
        if zlib.crc32(memoryview(data)[start:end]) != crc:
            damage = "a record is torn or fails its checksum"
            break
        if expected is not None and seq != expected:
            damage = f"its record has sequence number {seq} where {expected} was due"
            break
        records.append((seq, start, end))
        offset, expected = end, seq + 1
    first = records[0][0] if records else None
    return Scan("legacy", None, first, records, offset, damage, 0)


def header(database_id: bytes, first_seq: int) -> bytes:
    head = HEADER.pack(MAGIC, FORMAT, 0, database_id, first_seq, 0)[: HEADER.size - 4]
    return head + struct.pack("<I", zlib.crc32(head))


def frame(seq: int, payload: bytes) -> bytes:
    crc = zlib.crc32(payload, zlib.crc32(_CHECKED.pack(len(payload), seq)))
    return FRAME.pack(MARK, len(payload), seq, crc) + payload


class IngestLog:
    """One directory of segments; one appender thread at a time.

    ``database_id``: the 16 bytes naming the database this log belongs to;
    ``applied_seq``: the last record the database holds (numbering goes on
    above it even when the log lost its files); ``accept_legacy``: segments
    of format 1 may be replayed. Raises ``LogRefused`` (nothing changed)
    for a log that is not this database's."""

    def __init__(
        self,
        directory: str | Path,
        database_id: bytes,
        *,
        applied_seq: int = 0,
        accept_legacy: bool = False,
        segment_bytes: int = SEGMENT_BYTES,
    ):
        if len(database_id) != 16:
            raise ValueError("a database id is 16 bytes")
        self.directory = Path(directory)
        self.database_id = database_id
        self.segment_bytes = segment_bytes
        self.findings = Findings()
        self.directory.mkdir(parents=True, exist_ok=True)
        self._segments: list[Segment] = []
        self._fd: int | None = None
        self._size = 0
        self.last_seq = self._open(applied_seq, accept_legacy)

    # -- opening: check every segment, cut a tear, set damage aside -------------------------------

    def _open(self, applied_seq: int, accept_legacy: bool) -> int:
        """Read the directory through; the last sequence number in use."""
        candidates, unfinished = self._candidates()
        scans = [(path, scan_segment(path.read_bytes(), int(path.name[:18]))) for path in candidates]
        self._refuse_foreign(scans, accept_legacy)
        for path in unfinished:  # never renamed into place: nothing in it was acknowledged
            with contextlib.suppress(OSError):
                path.unlink()
        last = 0
        for i, (path, scan) in enumerate(scans):
            damage = self._damage(path, scan, last, applied_seq, is_last=i == len(scans) - 1)
            # Whole, torn at its end, or damaged after whole records: those stay.
            kept = damage is None or (bool(scan.records) and damage[0] == scan.end)
            if kept:
                segment = Segment(scan.first_seq or 0, path, legacy=scan.kind == "legacy")
                self._segments.append(segment)
                self.findings.legacy_segments += segment.legacy
                last = scan.records[-1][0]
            if damage is not None:
                first = last + 1 if last else int(path.name[:18])
                self._set_aside(scans[i:], *damage, kept=kept, first_seq=first, applied_seq=applied_seq)
                break
            if scan.damage is not None:  # a torn last write: cut it off
                self._cut(path, scan.end)
        if self.findings.ignored:
            log.warning(
                "ignored in the ingest log %s (not segments, left as they are): %s",
                self.directory,
                ", ".join(sorted(self.findings.ignored)),
            )
        return max(last, applied_seq)

    def _candidates(self) -> tuple[list[Path], list[Path]]:
        """The segment files in order, and the segments never renamed into
        place; anything else is noted."""
        found, unfinished = [], []
        for entry in sorted(self.directory.iterdir()):
            if entry.name == QUARANTINE and entry.is_dir():
                continue
            if entry.name.endswith(TMP_SUFFIX) and _SEGMENT_NAME.match(entry.name[: -len(".tmp")]):
                unfinished.append(entry)
            elif _SEGMENT_NAME.match(entry.name) and entry.is_file():
                found.append(entry)
            else:
                self.findings.ignored.append(entry.name)
        return found, unfinished

    def _refuse_foreign(self, scans: list[tuple[Path, Scan]], accept_legacy: bool) -> None:
        for path, scan in scans:
            if scan.kind == "current" and scan.database_id != self.database_id:
                raise LogRefused(
                    f"the ingest log {self.directory} belongs to another database "
                    f"({_uuid(scan.database_id)}; this one is {_uuid(self.database_id)}, segment {path.name}): "
                    "it is never replayed here. Move that directory away (or back beside its own database "
                    "file) and start again"
                )
            if scan.kind == "future":
                raise LogRefused(
                    f"the ingest log {self.directory} was written by a newer tsdb-service (segment {path.name}): "
                    "start that version to apply it, or move the directory away"
                )
            if scan.kind == "legacy" and not accept_legacy:
                raise LogRefused(
                    f"the ingest log {self.directory} holds segments without a database identity "
                    f"({path.name}, written before the log had headers), and this database has already "
                    "replayed its own: they may be another database's. Move them away and start again"
                )

    def _damage(self, path: Path, scan: Scan, last: int, applied_seq: int, is_last: bool) -> tuple[int, str] | None:
        """Where ``path``'s damage begins and why, or None. Where the segment
        has whole records before its damage they stay; else (a damaged
        header, a segment out of place, a damaged first record) the whole
        segment goes. A tear of the last write is not damage (the caller
        cuts it off); a segment's first group is durable before the segment
        exists, so its first record is never torn."""
        first = int(path.name[:18])
        if scan.kind == "damaged":
            return 0, scan.damage or "it has no valid header"
        if scan.first_seq != first:
            return 0, f"its header says it starts at {scan.first_seq}"
        if last and first <= last:
            return 0, f"it starts at {first}, overlapping the segment before it"
        # A log from before headers starts where its applied segments were
        # dropped, and the database only knows their row ids: no gap before it.
        if first > max(last, applied_seq) + 1 and (last or scan.kind != "legacy"):
            return 0, f"records {max(last, applied_seq) + 1} to {first - 1} are missing before it"
        if not scan.records:
            return scan.end, scan.damage or "it holds no record"
        if scan.damage is None or (is_last and scan.after == 0):
            return None
        return scan.end, scan.damage

    def _cut(self, path: Path, end: int) -> None:
        with open(path, "r+b") as f:
            size = os.fstat(f.fileno()).st_size
            f.truncate(end)
            os.fsync(f.fileno())
        self.findings.torn_bytes += size - end

    def _set_aside(
        self, scans: list[tuple[Path, Scan]], offset: int, reason: str, *, kept: bool, first_seq: int, applied_seq: int
    ) -> None:
        """Move the damage and everything after it into the quarantine: the
        segment's bytes from ``offset`` (the whole file unless it ``kept``
        records before it) and every later segment."""
        path, _ = scans[0]
        stamp = datetime.now(UTC).strftime("%Y%m%dT%H%M%S.%fZ")
        folder = self.directory / QUARANTINE / f"{stamp}-{path.stem}"
        folder.mkdir(parents=True, exist_ok=True)
        data = path.read_bytes()
        records = _records_in(data, offset)
        moved = len(data) - offset
        if not kept:
            moved = len(data)
            os.replace(path, folder / path.name)
        else:
            tail = folder / f"{path.name}.from-{offset}"
            tail.write_bytes(data[offset:])
            fsync_path(tail)
            with open(path, "r+b") as f:
                f.truncate(offset)
                os.fsync(f.fileno())
        for other, _ in scans[1:]:
            other_data = other.read_bytes()
            moved += len(other_data)
            records += _records_in(other_data, 0)
            os.replace(other, folder / other.name)
        _fsync_directory(folder)
        _fsync_directory(self.directory)
        found = SetAside(path.name, offset, reason, first_seq, records, moved, len(scans) - 1, folder)
        self.findings.set_aside = found
        log.error(
            "the ingest log %s is damaged in segment %s at offset %d (%s): set aside %d records "
            "(%d bytes, with %d later segments) in %s; records from sequence number %d on are not replayed "
            "(the database holds every record up to %d). Inspect them, then move the quarantine folder away "
            "(docs/operations.md, 'The ingest log')",
            self.directory,
            path.name,
            offset,
            reason,
            records,
            moved,
            found.later_segments,
            folder,
            first_seq,
            applied_seq,
        )

    # -- reading ----------------------------------------------------------------------------

    def records(self, after_seq: int = 0) -> Iterator[tuple[int, bytes]]:
        """Every record with a sequence number above ``after_seq``, in order
        (those ``_open`` checked)."""
        segments = list(self._segments)
        for i, segment in enumerate(segments):
            if i + 1 < len(segments) and segments[i + 1].first_seq - 1 <= after_seq:
                continue  # wholly at or below after_seq
            data = segment.path.read_bytes()
            for seq, payload in scan_segment(data, segment.first_seq).payloads(data):
                if seq > after_seq:
                    yield seq, payload

    def quarantined(self) -> bool:
        """Whether the quarantine folder holds anything (an operator moves it away)."""
        folder = self.directory / QUARANTINE
        try:
            return any(folder.iterdir())
        except OSError:
            return False

    def has_legacy(self) -> bool:
        return any(s.legacy for s in self._segments)

    # -- appending --------------------------------------------------------------------------

    def append(self, payloads: list[bytes]) -> int:
        """Write one record per payload and make them durable; returns the
        last sequence number. Raises ``LogError`` with nothing appended."""
        if not payloads:
            return self.last_seq
        seq = self.last_seq
        frames = []
        for payload in payloads:
            seq += 1
            frames.append(frame(seq, payload))
        data = b"".join(frames)
        if self._fd is None or self._size + len(data) > self.segment_bytes:
            self._new_segment(self.last_seq + 1, data)
        else:
            self._write(self._fd, data)
        self.last_seq = seq
        return seq

    def _write(self, fd: int, data: bytes) -> None:
        try:
            written = os.write(fd, data)
            while written < len(data):
                written += os.write(fd, data[written:])
            os.fdatasync(fd)
        except OSError as exc:
            self._undo(fd)
            raise LogError(f"the ingest log could not be written: {exc}") from exc
        self._size += len(data)

    def _new_segment(self, first_seq: int, frames: bytes) -> None:
        """A new segment holding ``frames``, whole before it has its name."""
        self.close()
        path = self.directory / f"{first_seq:018d}{SUFFIX}"
        tmp = self.directory / (path.name + ".tmp")
        content = header(self.database_id, first_seq) + frames
        fd = None
        try:
            if path.exists():
                raise FileExistsError(f"{path} already exists")
            fd = os.open(tmp, os.O_WRONLY | os.O_APPEND | os.O_CREAT | os.O_TRUNC, 0o600)
            written = os.write(fd, content)
            while written < len(content):
                written += os.write(fd, content[written:])
            os.fdatasync(fd)
            os.rename(tmp, path)
            _fsync_directory(self.directory)
        except OSError as exc:
            if fd is not None:
                os.close(fd)
            for leftover in (tmp, path) if fd is not None else ():
                with contextlib.suppress(OSError):
                    leftover.unlink()
            raise LogError(f"the ingest log could not be written: {exc}") from exc
        self._fd, self._size = fd, len(content)
        self._segments.append(Segment(first_seq, path))

    def _undo(self, fd: int) -> None:
        """Cut a failed append off the segment, so the next one starts whole."""
        try:
            os.ftruncate(fd, self._size)
        except OSError:
            self.close()  # the next append starts a new segment

    # -- dropping applied records -------------------------------------------------------------

    def drop_upto(self, applied_seq: int) -> int:
        """Delete the segments whose records are all applied (every record up
        to ``applied_seq``); never the one being written. Returns how many."""
        dropped = 0
        while len(self._segments) > 1 and self._segments[1].first_seq <= applied_seq + 1:
            segment = self._segments.pop(0)
            try:
                segment.path.unlink(missing_ok=True)
            except OSError as exc:  # applied: only space is lost; the next start drops it
                log.warning("could not delete the applied ingest-log segment %s: %s", segment.path, exc)
            dropped += 1
        return dropped

    def reset(self) -> None:
        """Delete every segment (all applied); numbering goes on from ``last_seq``."""
        self.close()
        for segment in self._segments:
            try:
                segment.path.unlink(missing_ok=True)
            except OSError as exc:
                log.warning("could not delete the applied ingest-log segment %s: %s", segment.path, exc)
        self._segments = []
        with contextlib.suppress(OSError):
            _fsync_directory(self.directory)

    def writable(self) -> bool:
        """Whether a new segment could be made in the directory now."""
        return os.access(self.directory, os.W_OK | os.X_OK)

    def bytes_on_disk(self) -> int:
        total = 0
        for segment in self._segments:
            with contextlib.suppress(OSError):
                total += segment.path.stat().st_size
        return total

    def close(self) -> None:
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None


def _records_in(data: bytes, offset: int) -> int:
    """Records set aside from ``data[offset:]``: every whole one, and the
    damaged one the bytes at ``offset`` began (0: a whole segment, whose
    header is no record)."""
    if offset == 0:
        scan = scan_segment(data)
        if scan.kind == "legacy":
            return len(scan.records) + (scan.damage is not None)
        return _whole_after(data, 0)
    whole = _whole_after(data, offset)
    return whole + (isinstance(_frame_at(data, offset), str) and offset < len(data))


def _uuid(raw: bytes | None) -> str:
    import uuid

    return str(uuid.UUID(bytes=raw)) if raw is not None and len(raw) == 16 else "?"


def fsync_path(path: Path) -> None:
    """Make a file's content, or a directory's entries, durable."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _fsync_directory(directory: Path) -> None:
    """Make a directory's entries durable (a new, renamed or deleted segment)."""
    fsync_path(directory)
