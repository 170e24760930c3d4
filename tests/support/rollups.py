"""Rollups against raw samples, every bucket: what the rollup tests assert.

``differences(store)`` lists each (level, sid, bucket) whose rollup rows
(merged and hot, combined) differ from the partial aggregate of its raw
samples, column by column; sums compared to a relative 1e-9 (additions in
another order). For stores where retention deleted nothing: there every
bucket must equal raw.
"""

from __future__ import annotations

import math

from tsdb_service.storage.rollups import COLUMNS, LEVELS, combine_partials, samples_partials


def differences(store) -> list[tuple]:
    q = store.querier()
    d = q.dialect
    out: list[tuple] = []
    for level in LEVELS:
        raw_sql = samples_partials(d, level, d.samples("sid, rid, t, kind, num"))
        raw = {(r[0], r[1]): r[2:] for r in q._fetch(raw_sql, [])}
        rolled = {(r[0], r[1]): r[2:] for r in q._fetch(combine_partials(d, level.view), [])}
        for key in sorted(set(raw) | set(rolled)):
            mine, theirs = rolled.get(key), raw.get(key)
            if mine is None or theirs is None:
                out.append((level.name, *key, "row", mine, theirs))
                continue
            for column, a, b in zip(COLUMNS[2:], mine, theirs, strict=True):
                same = (
                    math.isclose(a, b, rel_tol=1e-9)
                    if column == "num_sum" and a is not None and b is not None
                    else a == b
                )
                if not same:
                    out.append((level.name, *key, column, a, b))
    return out


def bucket_count(store) -> int:
    """Buckets of both levels the rollups hold."""
    q = store.querier()
    return sum(
        q._fetch(f"SELECT count(*) FROM (SELECT DISTINCT sid, bucket FROM {level.view}) AS k", [])[0][0]
        for level in LEVELS
    )
