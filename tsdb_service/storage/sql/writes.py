"""The write statements both SQL backends share: deletes and instance edits."""

from __future__ import annotations

from collections.abc import Sequence
from datetime import datetime

from tsdb_service.core.query import TimeRange
from tsdb_service.storage.columns import VALUE_COLUMNS, content_values
from tsdb_service.storage.rollups import Redo, recompute_statements
from tsdb_service.storage.sql.dialect import SqlDialect, quote_ident, series_time_filter
from tsdb_service.write.ops import DeleteInstance, ReplaceInstance


def delete_statements(
    dialect: SqlDialect, tables: Sequence[str], sids: Sequence[int], time: TimeRange, upto_rid: int
) -> list[tuple[str, list]]:
    """DELETEs for the samples of ``sids`` in ``time``, written up to ``upto_rid``
    (rows appended after the delete was asked for survive it), between the
    statements that recompute the rollups of the buckets they touch
    (``storage.rollups``)."""
    p = dialect.placeholder
    before, after = recompute_statements(dialect, Redo(sids, time, whole=True))
    out = list(before)
    for table in tables:
        where, params = series_time_filter(dialect, sids, time)
        where += f" AND rid <= {p}"
        params.append(upto_rid)
        out.append((f"DELETE FROM {quote_ident(table)} WHERE {where}", params))
    return out + after


def instance_statements(
    dialect: SqlDialect, tables: Sequence[str], op: DeleteInstance | ReplaceInstance
) -> list[tuple[str, list]]:
    """The statements of a ``DeleteInstance`` or ``ReplaceInstance`` op
    (``write.ops``): one per sample table, each touching the one sample
    (``sid``, ``iid``), between the statements that recompute the rollups of
    its buckets. A replacement keeps the instance id, series and row time,
    and the stored observedAt when the new content has none."""
    p = dialect.placeholder
    where = f"sid = {p} AND iid = {p}"
    before, after = recompute_statements(dialect, Redo((op.sid,), instance=(op.sid, op.iid)))
    out = list(before)
    for table in tables:
        if isinstance(op, DeleteInstance):
            out.append((f"DELETE FROM {quote_ident(table)} WHERE {where}", [op.sid, op.iid]))
            continue
        a = op.attr
        values = [
            *content_values(a),
            _time_or_none(dialect, a.deleted_at),
            dialect.time_value(op.modified_at),
            _time_or_none(dialect, a.observed_at),
        ]
        sets = ", ".join(f"{c} = {p}" for c in (*VALUE_COLUMNS, "deleted_at", "modified_at"))
        sets += f", observed_at = coalesce(CAST({p} AS TIMESTAMP), observed_at)"
        out.append((f"UPDATE {quote_ident(table)} SET {sets} WHERE {where}", [*values, op.sid, op.iid]))
    return out + after


def _time_or_none(dialect: SqlDialect, moment: datetime | None) -> object:
    return None if moment is None else dialect.time_value(moment)
