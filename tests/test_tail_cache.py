"""The in-memory tail answers exactly what the database would, or nothing.

A random model run: batches of samples (late and duplicate times included)
are committed and published while reads with random windows, limits and
offsets ask the tail; whenever it answers, the answer must equal the one
computed from all committed rows.
"""

from __future__ import annotations

import random

import pytest

from tsdb_service.core.timefmt import iso_ms_us as iso_ms
from tsdb_service.storage.duckdb.tail_cache import TailCache

SID = 7


def _expected(truth, start, end, newest_first, limit, offset):
    rows = sorted(r for r in truth if (start is None or r[0] >= start) and (end is None or r[0] <= end))
    if newest_first:
        picked = rows[::-1][offset : offset + limit]
        return picked[::-1]
    return rows[offset : offset + limit]


def _cols(rows):
    return {
        "sid": [SID] * len(rows),
        "t": [r[0] for r in rows],
        "rid": [r[1] for r in rows],
        "kind": [r[3] for r in rows],
        "num": [r[4] for r in rows],
        "txt": [r[5] for r in rows],
        "js": [r[6] for r in rows],
    }


@pytest.mark.parametrize("seed", range(8))
def test_tail_answers_match_the_database(seed):
    rnd = random.Random(seed)
    cache = TailCache(max_series=4, rows=16)
    truth: list[tuple] = []
    rid = 0
    answered = 0

    def load(sid, n):  # the database: newest n committed rows, newest first
        assert sid == SID
        return sorted(truth, reverse=True)[:n]

    for _ in range(300):
        if rnd.random() < 0.4:
            batch = []
            for _ in range(rnd.randint(1, 5)):
                rid += 1
                # mostly increasing times, some late and some equal ones
                t = (rid * 10 if rnd.random() < 0.8 else rnd.randint(0, rid * 10)) * 1_000
                batch.append((t, rid, iso_ms(t), 1, float(rid), None, None))
            truth.extend(batch)
            cache.publish(_cols(batch))
        else:
            start = rnd.choice([None, rnd.randint(0, rid * 10_000 + 1)])
            end = rnd.choice([None, rnd.randint(0, rid * 10_000 + 1)])
            newest_first = rnd.random() < 0.7
            limit, offset = rnd.randint(1, 12), rnd.randint(0, 4)
            got = cache.rows(SID, load, start, end, newest_first, limit, offset)
            if got is not None:
                answered += 1
                assert got == _expected(truth, start, end, newest_first, limit, offset)
        if rnd.random() < 0.02:
            cache.drop([SID])
    assert answered > 20


def test_a_load_that_raced_a_commit_is_not_installed():
    cache = TailCache(max_series=4, rows=8)
    truth = [(1000, 1, iso_ms(1000), 1, 1.0, None, None)]

    def racing_load(sid, n):
        rows = sorted(truth, reverse=True)[:n]
        late = (2000, 2, iso_ms(2000), 1, 2.0, None, None)  # committed after the query ran
        truth.append(late)
        cache.publish(_cols([late]))
        return rows

    assert cache.rows(SID, racing_load, None, None, True, 5, 0) == [truth[0]]
    # Not installed: the next read loads again and sees both samples.
    assert cache.rows(SID, lambda s, n: sorted(truth, reverse=True)[:n], None, None, True, 5, 0) == truth


def test_requests_beyond_the_tail_fall_back():
    cache = TailCache(max_series=4, rows=8)
    truth = [(t * 1000, t, iso_ms(t * 1000), 1, float(t), None, None) for t in range(1, 21)]
    load = lambda sid, n: sorted(truth, reverse=True)[:n]  # noqa: E731
    assert cache.rows(SID, load, None, None, True, 5, 0) == truth[-5:]
    assert cache.rows(SID, load, None, None, False, 5, 0) is None  # oldest rows are not cached
    assert cache.rows(SID, load, None, None, True, 9, 0) is None  # more than the tail holds
    assert cache.rows(SID, load, None, 5_000, True, 2, 0) is None  # window before the tail


def test_iso_format_matches_the_sql_renderer():
    assert iso_ms(1_714_557_600_123_456) == "2024-05-01T10:00:00.123+00:00"
