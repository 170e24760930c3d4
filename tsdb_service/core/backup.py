"""What a backup (or a restore) of a store says it did, and checked.

A backup copies one consistent moment of a store, everything acknowledged
before it included, then reads the copy back: every table's row count and
a sample of rows must equal the store's at that moment. ``BackupReport``
carries the result to whoever asked (``tsdb-service backup`` and
``restore``, ``POST /admin/backup``), ``BackupRefused`` the reason there is
none, ``BackupNotVerified`` a copy that did not check out (not kept).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from tsdb_service.core.errors import Conflict, TsdbError


class BackupRefused(Conflict):
    """A backup or restore that must not run (a target that exists, a store
    in use, a backend with its own tools); the message says what to do."""


class BackupNotVerified(TsdbError):
    """The copy, read back, differs from its source: it was not kept. A
    bug, or a disk that does not keep what it is given."""

    status = 500


@dataclass(frozen=True, slots=True)
class TableCount:
    table: str
    source: int  # rows in the store (the backup, for a restore) at the copied moment
    copy: int  # rows in the copy, read back


@dataclass(frozen=True, slots=True)
class BackupReport:
    path: str  # the copy
    bytes: int
    seconds: float
    database_id: str  # the copy's (a restore gives it a new one)
    log_seq: int  # the ingest-log record the copy holds everything up to
    tables: tuple[TableCount, ...]
    sampled: int  # rows compared value by value
    mismatched: int  # of them, rows that differ or are missing from the copy

    @property
    def verified(self) -> bool:
        return self.mismatched == 0 and all(t.source == t.copy for t in self.tables)

    def as_json(self) -> dict[str, Any]:
        return {
            "path": self.path,
            "bytes": self.bytes,
            "seconds": round(self.seconds, 3),
            "databaseId": self.database_id,
            "ingestLogSeq": self.log_seq,
            "tables": {t.table: {"source": t.source, "copy": t.copy} for t in self.tables},
            "sampledRows": self.sampled,
            "mismatchedRows": self.mismatched,
            "verified": self.verified,
        }

    @classmethod
    def from_json(cls, doc: dict[str, Any]) -> BackupReport:
        return cls(
            str(doc["path"]),
            int(doc["bytes"]),
            float(doc["seconds"]),
            str(doc["databaseId"]),
            int(doc["ingestLogSeq"]),
            tuple(TableCount(name, int(c["source"]), int(c["copy"])) for name, c in doc["tables"].items()),
            int(doc["sampledRows"]),
            int(doc["mismatchedRows"]),
        )

    def lines(self, what: str = "backup") -> list[str]:
        """The report as a command prints it."""
        counts = ", ".join(
            f"{t.table} {t.copy}" if t.source == t.copy else f"{t.table} {t.copy} (store: {t.source})"
            for t in self.tables
        )
        verdict = "verified" if self.verified else "NOT VERIFIED"
        return [
            f"{what} written: {self.path} ({self.bytes} bytes, {self.seconds:.1f} s), database {self.database_id}, "
            f"ingest log applied up to record {self.log_seq}",
            f"rows per table: {counts}",
            f"{verdict}: every table's row count, and {self.sampled - self.mismatched} of {self.sampled} "
            "sampled rows equal value by value",
        ]
