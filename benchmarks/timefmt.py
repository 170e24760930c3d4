"""Epoch microseconds or ISO strings from the querier? (issue 11, item 4)

The history API answers ISO 8601 strings (``...T10:00:00.123+00:00``);
Grafana wants epoch milliseconds. Today the SQL renderer formats the time in
the database and Grafana parses the string back. The alternative is that the
querier returns epoch microseconds and each API formats at its edge: history
in Python, Grafana by an integer division.

This measures both on a realistic row set (10,000 samples of one series, the
shape ``fetch_samples`` reads), on DuckDB and PostgreSQL: the SQL fetch with
each time expression, then what each API does with the value.

    .venv/bin/python benchmarks/timefmt.py [--rows 10000] [--repeat 30]
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import duckdb

from tsdb_service.core.timefmt import epoch_ms, iso_ms_us
from tsdb_service.storage.duckdb.dialect import DuckDBDialect
from tsdb_service.storage.postgres.dialect import PostgresDialect


def _best(fn: Callable[[], object], repeat: int) -> float:
    """Median wall time of ``fn`` in milliseconds."""
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        fn()
        times.append((time.perf_counter() - start) * 1000)
    return statistics.median(times)


def _duckdb(rows: int, repeat: int) -> dict[str, float]:
    d = DuckDBDialect()
    with tempfile.TemporaryDirectory() as tmp:
        con = duckdb.connect(str(Path(tmp) / "t.duckdb"))
        con.execute(
            "CREATE TABLE s AS SELECT TIMESTAMP '2024-05-01 00:00:00' + to_microseconds(i * 1_000_123) AS t, "
            "i::DOUBLE AS num FROM range(?) r(i)",
            [rows],
        )
        iso_sql = f"SELECT {d.iso_ms('t')}, num FROM s ORDER BY t"
        us_sql = f"SELECT {d.epoch_us('t')}, num FROM s ORDER BY t"
        return _measure(lambda sql: con.execute(sql).fetchall(), iso_sql, us_sql, repeat)


def _postgres(rows: int, repeat: int) -> dict[str, float] | None:
    try:
        import pgutil  # noqa: F401  (puts the repository root on sys.path)
        import psycopg

        from tests.support.pg_cluster import PgCluster
    except ImportError:
        return None
    d = PostgresDialect()
    with PgCluster() as cluster, psycopg.connect(cluster.url) as con:
        con.execute(
            "CREATE TABLE s AS SELECT timestamp '2024-05-01' + i * interval '1000123 microseconds' AS t, "
            "i::float8 AS num FROM generate_series(0, %s - 1) i",
            [rows],
        )
        iso_sql = f"SELECT {d.iso_ms('t')}, num FROM s ORDER BY t"
        us_sql = f"SELECT {d.epoch_us('t')}, num FROM s ORDER BY t"
        return _measure(lambda sql: con.execute(sql).fetchall(), iso_sql, us_sql, repeat)


def _measure(fetch: Callable[[str], list], iso_sql: str, us_sql: str, repeat: int) -> dict[str, float]:
    iso_rows, us_rows = fetch(iso_sql), fetch(us_sql)
    assert [iso_ms_us(r[0]) for r in us_rows] == [r[0] for r in iso_rows]
    fetch_iso = _best(lambda: fetch(iso_sql), repeat)
    fetch_us = _best(lambda: fetch(us_sql), repeat)
    parse_back = _best(lambda: [epoch_ms(r[0]) for r in iso_rows], repeat)
    format_iso = _best(lambda: [iso_ms_us(r[0]) for r in us_rows], repeat)
    to_ms = _best(lambda: [r[0] // 1000 for r in us_rows], repeat)
    return {
        "history, ISO from SQL": fetch_iso,
        "history, epoch from SQL + Python format": fetch_us + format_iso,
        "grafana, ISO from SQL + parse back": fetch_iso + parse_back,
        "grafana, epoch from SQL + // 1000": fetch_us + to_ms,
        "(fetch ISO)": fetch_iso,
        "(fetch epoch)": fetch_us,
        "(parse back)": parse_back,
        "(format in Python)": format_iso,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rows", type=int, default=10_000)
    parser.add_argument("--repeat", type=int, default=30)
    parser.add_argument("--no-postgres", action="store_true")
    args = parser.parse_args()
    results = {"duckdb": _duckdb(args.rows, args.repeat)}
    if not args.no_postgres:
        pg = _postgres(args.rows, args.repeat)
        if pg is not None:
            results["postgresql"] = pg
    print(f"{args.rows} rows, median of {args.repeat} runs, ms")
    for backend, figures in results.items():
        print(backend)
        for name, ms in figures.items():
            print(f"  {name:<42} {ms:8.2f}")


if __name__ == "__main__":
    main()
