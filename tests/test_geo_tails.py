"""Geo ``lastN`` answered from tails loaded together (issue 15).

On DuckDB a newest-first read under a geo mask loads the in-memory tails of
the matched series it misses in one statement and answers from them where
they provably hold the newest matching samples (tsdb_service/storage/duckdb/
querier.py, ``_masked_rows``), so asking again reads no samples. The answer
must be the one the database gives: the same query asked twice, between new
notifications, late ones and deletes, always equals the model of
test_geo_samples, with tails far smaller than the series (most answers
cannot come from them) and larger (most can). PostgreSQL answers the same
from its index; both backends run it.
"""

from __future__ import annotations

import random

import pytest

from tests.test_geo_samples import QUERIES, _drive, _got


@pytest.mark.parametrize("rows", [3, 64])
def test_repeated_geo_lastn_equals_the_model(client_factory, store_url_factory, rows):
    with client_factory(store_url_factory(f"geo_tails_{rows}"), tail_cache_rows=rows) as client:
        _drive(client, random.Random(1500 + rows), 260)


def test_a_repeated_query_answers_the_same(client_factory, store_url_factory):
    """Once from the database (loading the tails), then from memory."""
    with client_factory(store_url_factory("geo_tails_again"), tail_cache_rows=8) as client:
        _drive(client, random.Random(15), 120)
        for geo, _ in QUERIES.values():
            for params in ({"lastN": 3}, {"lastN": 8}, {"lastN": 9}, {"limit": 4, "offset": 2}):
                assert _got(client, geo, params) == _got(client, geo, params), (geo, params)
