"""The DuckDB database's identity and its ingest-log position (migration 0013).

``store_state`` has one row: the database's id (``write.log`` writes it
into every segment and refuses a log naming another), the ingest-log
position it holds (``write.ops.LogPosition``), and whether its log may
still hold segments without identity (written before the upgrade).

The position moves in the same transaction as the samples of each applied
batch (``ADVANCE_SQL``, in the writer: ``appender``); only the writer and
the store's start write this table.
"""

from __future__ import annotations

import uuid
from dataclasses import dataclass

import duckdb

from tsdb_service.write.ops import LogPosition

LOAD_SQL = "SELECT database_id, log_applied_seq, log_applied_rid, log_legacy FROM store_state"
ADVANCE_SQL = (
    "UPDATE store_state SET log_applied_seq = greatest(log_applied_seq, ?), "
    "log_applied_rid = greatest(log_applied_rid, ?)"
)
POSITION_SQL = "SELECT log_applied_seq, log_applied_rid FROM store_state"
NO_LEGACY_SQL = "UPDATE store_state SET log_legacy = false WHERE log_legacy"
NEW_IDENTITY_SQL = "UPDATE store_state SET database_id = uuid(), log_legacy = false"


@dataclass(frozen=True, slots=True)
class StoreState:
    database_id: uuid.UUID
    position: LogPosition
    legacy_log: bool


def load_state(cur: duckdb.DuckDBPyConnection) -> StoreState:
    rows = cur.execute(LOAD_SQL).fetchall()
    if len(rows) != 1:
        raise RuntimeError(f"store_state must hold one row, not {len(rows)}: the database was altered by hand")
    database_id, seq, rid, legacy = rows[0]
    return StoreState(_as_uuid(database_id), LogPosition(int(seq), int(rid)), bool(legacy))


def log_position(cur: duckdb.DuckDBPyConnection) -> LogPosition:
    [(seq, rid)] = cur.execute(POSITION_SQL).fetchall()
    return LogPosition(int(seq), int(rid))


def _as_uuid(value: object) -> uuid.UUID:
    return value if isinstance(value, uuid.UUID) else uuid.UUID(str(value))
