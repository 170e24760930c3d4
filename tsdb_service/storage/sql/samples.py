"""History reads over SQL: the selected rows, latest times and values, counts."""

from __future__ import annotations

from collections.abc import Sequence

from tsdb_service.core.query import LastValueRow, LatestRow, RawRow
from tsdb_service.read.requests import RowsRead, SamplesIn, ValuesAt
from tsdb_service.read.samples import SampleReader
from tsdb_service.storage.rollup_reads import rolled_up_count
from tsdb_service.storage.sql.dialect import MAX_BIGINT, latest_per_series, rows_as
from tsdb_service.storage.sql.reads import SqlReads

as_latest = rows_as(LatestRow)
as_last_values = rows_as(LastValueRow)


class SqlSamples(SqlReads, SampleReader):
    def raw_rows(self, ask: RowsRead) -> list[RawRow]:
        """See ``SampleReader``. One attribute per row needs no row grouping.

        Over many series a time threshold is computed first: the M-th newest
        sample time, M = (limit + offset) x attrs_per_row, can never be newer
        than the oldest wanted row, so ``t >= threshold`` keeps every wanted
        row while the expensive ordering only sees a few candidates.
        """
        sids, newest_first, limit, offset = ask.sids, ask.newest_first, ask.limit, ask.offset
        if not sids:
            return []
        d = self.dialect
        p = d.placeholder
        where, params = self._where(sids, ask.time, ask.mask)
        direction = "DESC" if newest_first else "ASC"
        cols = f"sid, rid, {d.iso_ms('t')}, kind, num, txt, js"
        table = d.samples("sid, rid, t, kind, num, txt, js")
        if len(sids) > 1:
            bound = "min" if newest_first else "max"
            cmp = ">=" if newest_first else "<="
            where_thr = (
                f"{where} AND t {cmp} (SELECT {bound}(t) FROM (SELECT t FROM {table} WHERE {where} "
                f"ORDER BY t {direction} LIMIT {p}) candidates)"
            )
            per_row = 1 if ask.one_per_row else max(1, ask.attrs_per_row)
            params_thr = [*params, *params, min((limit + offset) * per_row, MAX_BIGINT)]
        else:
            where_thr, params_thr = where, params
        if ask.one_per_row:
            sql = (
                f"SELECT {cols} FROM {table} WHERE {where_thr} "
                f"ORDER BY t {direction}, rid {direction} LIMIT {p} OFFSET {p}"
            )
            rows = self._fetch(sql, [*params_thr, limit, min(offset, MAX_BIGINT)])
            if newest_first:
                rows.reverse()
            return rows
        pick = "max" if newest_first else "min"
        sql = (
            f"SELECT {cols} FROM {table} WHERE {where_thr} AND rid IN ("
            f"SELECT rid FROM {table} WHERE {where_thr} GROUP BY rid "
            f"ORDER BY {pick}(t) {direction}, rid {direction} LIMIT {p} OFFSET {p}) "
            f"ORDER BY t, rid"
        )
        return self._fetch(sql, [*params_thr, *params_thr, limit, min(offset, MAX_BIGINT)])

    def latest_index(self, ask: SamplesIn) -> list[LatestRow]:
        if not ask.sids:
            return []
        mask = ask.mask
        where, params = self._where(ask.sids, ask.time, mask)
        d = self.dialect
        sql = f"SELECT sid, {d.iso_ms('max(t)')} FROM {self._samples('sid, t', mask)} WHERE {where} GROUP BY sid"
        return as_latest(self._fetch(sql, params))

    def last_values(self, sids: Sequence[int]) -> list[LastValueRow]:
        return self._latest(sids, "", [])

    def values_at(self, ask: ValuesAt) -> list[LastValueRow]:
        """See ``SampleReader``: ``last_values`` among the samples at or
        before the instant (an index on (sid, t) serves it on PostgreSQL)."""
        d = self.dialect
        return self._latest(ask.sids, f" AND t <= {d.placeholder}", [d.time_value(ask.at)])

    def _latest(self, sids: Sequence[int], where_more: str, params_more: list) -> list[LastValueRow]:
        """Each series' newest sample among those matching ``where_more``."""
        if not sids:
            return []
        d = self.dialect
        where, params = d.sid_filter(sids)
        source = d.samples("sid, rid, t, kind, atype, num, txt, js")
        columns = "kind, atype, num, txt, js"
        sql = latest_per_series(
            f"sid, {d.iso_ms('t')}, {columns}", source, where + where_more, inner=f"sid, t, {columns}"
        )
        return as_last_values(self._fetch(sql, [*params, *params_more]))

    def count(self, ask: SamplesIn) -> int:
        """See ``SampleReader``; the rolled-up hours come from ``storage.rollups``."""
        sids, time, mask = ask.sids, ask.time, ask.mask
        if not sids:
            return 0
        where, params = self._where(sids, time, mask)
        rows = self._fetch(f"SELECT count(*) FROM {self._samples('sid, t', mask)} WHERE {where}", params)
        raw = int(rows[0][0]) if rows else 0
        if raw or mask is not None:
            return raw
        return rolled_up_count(self, sids, time)  # what only rollups hold (retention)
