"""NGSI-LD instance reads over SQL, rendered by ``storage.sql.temporal``."""

from __future__ import annotations

from collections.abc import Sequence

import orjson

from tsdb_service.core.model import client_instance_id, instance_iid
from tsdb_service.core.query import TIME_PROPERTIES, InstanceAggregateRow, InstanceRow, InstanceValueRow, InstanceWindow
from tsdb_service.read.instances import SeparateScans, TemporalReader
from tsdb_service.read.requests import (
    InstanceAggregateRead,
    InstanceLocations,
    InstanceLookup,
    InstancePage,
    InstancesIn,
    InstancesMatching,
    InstancesRead,
)
from tsdb_service.storage.sql import temporal
from tsdb_service.storage.sql.dialect import MAX_BIGINT
from tsdb_service.storage.sql.reads import SqlReads

_INSTANCE_COLUMNS = "sid, iid, t, observed_at, created_at, modified_at, deleted_at, kind, atype, num, txt, js, md"
_INSTANCE_SELECT = (
    "sid, iid, {at} AS at_time, t, observed_at, created_at, modified_at, deleted_at, kind, atype, num, txt, js, md"
)
_INSTANCE_NAMES = (
    "sid, iid, at_time, t, observed_at, created_at, modified_at, deleted_at, kind, atype, num, txt, js, md"
)


def _instance_order(row: InstanceRow) -> tuple:
    return row.sid, row.at, row.iid


class SqlInstances(SqlReads, SeparateScans, TemporalReader):
    def temporal_instances(self, ask: InstancesRead) -> list[InstanceRow]:
        """See ``TemporalReader``."""
        sids, window, last_n, limit = ask.sids, ask.window, ask.last_n, ask.limit
        if not sids:
            return []
        d = self.dialect
        p = d.placeholder
        at, in_window, window_params = temporal.window_filter(d, window, self._untimed(sids, window))
        where, params = d.sid_filter(sids)
        where += f" AND {in_window}"
        params += window_params
        table = d.samples(_INSTANCE_COLUMNS)
        cols = _INSTANCE_SELECT.format(at=at)
        direction = "DESC" if ask.newest_first or last_n is not None else "ASC"
        if last_n is not None:
            inner = (
                f"SELECT {cols}, row_number() OVER (PARTITION BY sid ORDER BY {at} DESC, iid DESC) AS rn "
                f"FROM {table} WHERE {where}"
            )
            sql = f"SELECT {_INSTANCE_NAMES} FROM ({inner}) ranked WHERE rn <= {p}"
            params.append(min(last_n, MAX_BIGINT))
            order = f"at_time {direction}, iid {direction}"
        else:
            sql = f"SELECT {cols} FROM {table} WHERE {where}"
            order = f"{at} {direction}, iid {direction}"
        if limit is not None:
            sql += f" ORDER BY {order} LIMIT {p}"
            params.append(min(limit, MAX_BIGINT))
        return self._instance_rows(sids, self._fetch(sql, params))

    def instance_page(self, ask: InstancePage) -> tuple[list[InstanceRow], int | None]:
        """See ``TemporalReader``: each series' instances ranked in the
        window (``row_number``), those of the page's ranks read rank by rank
        (``ORDER BY rn``) up to the limit, with the window's largest
        instance id (``max(iid) OVER ()``, before the ranks are cut)."""
        sids = ask.sids
        if not sids:
            return [], ask.through_iid
        d = self.dialect
        p = d.placeholder
        at, in_window, window_params = temporal.window_filter(d, ask.window, self._untimed(sids, ask.window))
        where, params = d.sid_filter(sids)
        where += f" AND {in_window}"
        params += window_params
        if ask.through_iid is not None:
            where += f" AND iid <= {p}"
            params.append(min(ask.through_iid, MAX_BIGINT))
        direction = "ASC" if ask.ascending else "DESC"
        inner = (
            f"SELECT {_INSTANCE_SELECT.format(at=at)}, "
            f"row_number() OVER (PARTITION BY sid ORDER BY {at} {direction}, iid {direction}) AS rn, "
            f"max(iid) OVER () AS top FROM {d.samples(_INSTANCE_COLUMNS)} WHERE {where}"
        )
        ranks = f"rn > {p}"
        params.append(min(ask.offset, MAX_BIGINT))
        if ask.size is not None:
            ranks += f" AND rn <= {p}"
            params.append(min(ask.offset + ask.size, MAX_BIGINT))
        sql = f"SELECT {_INSTANCE_NAMES}, top FROM ({inner}) ranked WHERE {ranks} ORDER BY rn, sid LIMIT {p}"
        params.append(min(ask.limit, MAX_BIGINT))
        fetched = self._fetch(sql, params)
        top = ask.through_iid if ask.through_iid is not None else max((row[-1] for row in fetched), default=None)
        return self._instance_rows(sids, [row[:-1] for row in fetched]), top

    def _instance_rows(self, sids: Sequence[int], fetched: list[tuple]) -> list[InstanceRow]:
        """Driver rows (``_INSTANCE_NAMES``) as ``InstanceRow``, sorted by
        (sid, time property, instance id), with their series' datasetId."""
        refs = self.catalog.refs(sids)
        rows = [
            InstanceRow(
                sid,
                iid,
                at_,
                t,
                obs,
                cre,
                mod,
                dele,
                ref.dataset_id if ref is not None else None,
                kind,
                atype,
                num,
                txt,
                js,
                md,
            )
            for sid, iid, at_, t, obs, cre, mod, dele, kind, atype, num, txt, js, md in fetched
            for ref in (refs.get(sid),)
        ]
        rows.sort(key=_instance_order)
        return rows

    def instance_at(self, ask: InstanceLookup) -> tuple[int, int] | None:
        """See ``TemporalReader``."""
        sids = ask.sids
        if not sids:
            return None
        d = self.dialect
        where, params = d.sid_filter(sids)
        iid = instance_iid(ask.instance_id)
        if iid is not None:
            rows = self._fetch(
                f"SELECT sid, iid FROM {d.samples('sid, iid')} WHERE {where} AND iid = {d.placeholder}", [*params, iid]
            )
            return (rows[0][0], rows[0][1]) if rows else None
        # A client's instanceId is a member of md: the rows whose text holds
        # it, then the member itself (a sub-property could hold the text).
        rows = self._fetch(
            f"SELECT sid, iid, md FROM {d.samples('sid, iid, md')} WHERE {where} "
            f"AND md LIKE {d.placeholder} ESCAPE '\\'",
            [*params, f"%{_like_escaped(orjson.dumps({'instanceId': ask.instance_id}).decode()[1:-1])}%"],
        )
        return next(((sid, iid) for sid, iid, md in rows if client_instance_id(md) == ask.instance_id), None)

    def instances_matching(self, ask: InstancesMatching) -> set[int]:
        """See ``TemporalReader``."""
        sids, window, test = ask.sids, ask.window, ask.test
        if not sids:
            return set()
        head, where, params = temporal.matching_parts(self.dialect, window, test, self._untimed(sids, window))
        return {row[0] for row in self._per_series(head, where, params, sids)}

    def instance_values(self, ask: InstancesIn) -> list[InstanceValueRow]:
        """See ``TemporalReader``."""
        sids, window = ask.sids, ask.window
        if not sids:
            return []
        head, where, params = temporal.values_parts(self.dialect, window, self._untimed(sids, window))
        return self._per_series(head, where, params, sids)

    def location_instances(self, ask: InstanceLocations) -> list[tuple[int, str]]:
        """See ``TemporalReader``."""
        sids, window, prefilter = ask.sids, ask.window, ask.prefilter
        if not sids:
            return []
        head, where, params = temporal.locations_parts(self.dialect, window, prefilter, self._untimed(sids, window))
        return self._per_series(head, where, params, sids)

    def instance_aggregate(self, ask: InstanceAggregateRead) -> list[InstanceAggregateRow]:
        """See ``TemporalReader``."""
        sids, window, methods, periods = ask.sids, ask.window, ask.methods, ask.periods
        if not sids:
            return []
        sql, params = temporal.aggregate_sql(self.dialect, sids, window, methods, periods, self._untimed(sids, window))
        return self._fetch(sql, params)

    def instance_span(self, ask: InstancesIn) -> tuple[int, int] | None:
        """See ``TemporalReader``."""
        sids, window = ask.sids, ask.window
        if not sids:
            return None
        rows = self._fetch(*temporal.span_sql(self.dialect, sids, window, self._untimed(sids, window)))
        if not rows or rows[0][0] is None:
            return None
        return int(rows[0][0]), int(rows[0][1])

    def _untimed(self, sids: Sequence[int], window: InstanceWindow) -> Sequence[int] | None:
        """Those of ``sids`` that can hold instances without observedAt, when
        the backend keeps that list and the window needs it (see
        ``temporal.window_filter``); None: any of them can."""
        return None

    def _per_series(self, head: str, where: str, params: list, sids: Sequence[int]) -> list:
        """``{head} WHERE <sid in sids> AND {where}``, all rows."""
        where_s, params_s = self.dialect.sid_filter(sids)
        return self._fetch(f"{head} WHERE {where_s} AND {where}", [*params_s, *params])


def _like_escaped(text: str) -> str:
    """``text`` as a literal in a LIKE pattern with ESCAPE '\\'."""
    return text.replace("\\", "\\\\").replace("%", "\\%").replace("_", "\\_")


# NGSI-LD time properties → the SQL that reads them (``storage.sql.temporal``).
assert tuple(temporal.TIME_PROPERTY_SQL) == TIME_PROPERTIES
