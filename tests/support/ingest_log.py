"""What a crash leaves in a DuckDB store's ingest log, for the tests of its
replay, its integrity checks and the deletes it must honour.

    leave_unapplied(db_path, [ops(...)])   # records acknowledged, not applied
    segments(db_path)                      # the log's segment files, in order

``leave_unapplied`` opens the store as the service does, appends the
records to its log exactly as the log writer would (row ids from the
store's ids owner, encoded by ``write.codec``), and closes it without
handing them to the applier: the state a SIGKILL leaves between a
notification's acknowledgement and its application.
"""

from __future__ import annotations

from datetime import UTC, datetime, timedelta
from pathlib import Path

from tsdb_service.core.model import AttrSample, EntitySample, Kind
from tsdb_service.storage.duckdb.store import LOG_SUFFIX, DuckDBStore
from tsdb_service.write import codec
from tsdb_service.write.ops import AppendSamples

__all__ = ["T0", "leave_unapplied", "log_dir", "readings", "segments"]

T0 = datetime(2024, 5, 1, tzinfo=UTC)


def readings(tenant: str, entity_id: str, values: range | list[int], attr: str = "level") -> AppendSamples:
    """One record: one notification per value, for ``entity_id`` (type
    ``Tank``), ``value`` seconds after ``T0``, carrying ``value + 0.25``."""
    return AppendSamples(
        [
            EntitySample(
                tenant,
                "/",
                entity_id,
                "Tank",
                T0 + timedelta(seconds=v),
                [AttrSample(attr, "Number", Kind.NUMBER, num=v + 0.25)],
            )
            for v in values
        ]
    )


def leave_unapplied(db_path: str | Path, records: list[AppendSamples], *, segment_bytes: int | None = None) -> None:
    """Append ``records`` to ``db_path``'s ingest log as acknowledged and
    never applied (one record each); ``segment_bytes``: rotate segments at
    that size while doing so."""
    store = DuckDBStore(str(db_path))
    try:
        logged = store.ingest_log
        assert logged is not None, "the ingest log is off"
        if segment_bytes is not None:
            logged.log.segment_bytes = segment_bytes
        for op in records:
            first = store.ids.take_rids(len(op.entities))
            for n, entity in enumerate(op.entities):
                entity.rid = first + n
            logged.log.append([codec.encode(op)])
    finally:
        store.close()


def log_dir(db_path: str | Path) -> Path:
    return Path(str(db_path) + LOG_SUFFIX)


def segments(db_path: str | Path) -> list[Path]:
    """The log's segment files, oldest first (their names sort as their order)."""
    return sorted(log_dir(db_path).glob("*.seg"))
