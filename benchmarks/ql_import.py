"""Import benchmark: ``tsdb-service import quantumleap`` samples per second.

    .venv/bin/python benchmarks/ql_import.py                        # 10M samples into DuckDB
    .venv/bin/python benchmarks/ql_import.py --samples 20000        # a quick check
    .venv/bin/python benchmarks/ql_import.py --target postgresql [--samples N] [--json FILE]

1. Starts a private PostgreSQL (``pgutil.BenchCluster``) and fills one
   QuantumLeap-layout table (``commands.quantumleap.layout``: schema
   ``mtbench``, table ``etdevice``, ``md_ets_metadata``) with ``--samples``
   samples: 1,000 devices, rows of 5 attributes (Number, Integer, Text,
   Boolean, DateTime), one row every second per device, loaded with COPY
   (not timed).
2. Imports it with the library call the command uses
   (``import_quantumleap``) into a new DuckDB file or a second PostgreSQL
   database, with the command's defaults (50,000 samples a batch), and
   times it: reading, converting, writing and the final check.
3. Prints samples/s and rows/s for the whole import, and the check's share.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from datetime import UTC, datetime, timedelta
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from pgutil import BenchCluster  # puts the repository on sys.path

ATTRS = 5  # samples per row
DEVICES = 1_000
T0 = datetime(2024, 1, 1, tzinfo=UTC)


def fill(url: str, samples: int) -> int:
    """A QuantumLeap table of ``samples`` samples (rows of ``ATTRS``); the rows written."""
    import psycopg

    from tsdb_service.commands.quantumleap.layout import copy_rows, table_name, write_entities

    rows = max(1, samples // ATTRS)
    first = {
        "id": "Device:0",
        "type": "Device",
        "temperature": {"type": "Number", "value": 20.5},
        "count": {"type": "Integer", "value": 1},
        "status": {"type": "Text", "value": "ok"},
        "on": {"type": "Boolean", "value": True},
        "seen": {"type": "DateTime", "value": T0.isoformat()},
    }
    columns = ["entity_id", "entity_type", "time_index", "fiware_servicepath", "instanceid"]
    columns += ["temperature", "count", "status", "on", "seen"]
    with psycopg.connect(url, autocommit=True) as conn:
        write_entities(conn, "bench", [(first, T0 - timedelta(days=1), "/")])  # creates the layout
        with conn.transaction():
            copy_rows(conn, table_name("bench", "Device"), columns, _rows(rows - 1))
        conn.execute('ANALYZE "mtbench"."etdevice"')
    return rows


def _rows(n: int):
    for i in range(n):
        device, second = i % DEVICES, i // DEVICES
        moment = T0 + timedelta(seconds=second, microseconds=device)
        yield (
            f"Device:{device}",
            "Device",
            moment,
            "/",
            f"urn:ngsi-ld:{i:032x}",
            20 + (i % 100) / 10,
            i,
            "ok" if i % 7 else "alarm",
            i % 2 == 0,
            moment,
        )


def run(samples: int, target_kind: str) -> dict:
    from tsdb_service.commands.quantumleap.importer import import_quantumleap
    from tsdb_service.core.config import Settings
    from tsdb_service.storage import open_store

    with BenchCluster("ql_source") as pg, tempfile.TemporaryDirectory() as tmp:
        assert pg.url is not None
        started = time.perf_counter()
        rows = fill(pg.url, samples)
        load_s = time.perf_counter() - started
        target_db = pg.cluster.database("ql_target") if target_kind == "postgresql" else str(Path(tmp) / "t.duckdb")
        store = open_store(Settings(db=target_db))
        try:
            started = time.perf_counter()
            report = import_quantumleap(pg.url, store, progress=sys.stderr.isatty())
            import_s = time.perf_counter() - started
            started = time.perf_counter()
            store.querier().type_counts()  # what the final check costs (it ran once inside the import)
            check_s = time.perf_counter() - started
        finally:
            store.close()
    return {
        "samples": report.samples,
        "rows": rows,
        "target": target_kind,
        "load_s": round(load_s, 2),
        "import_s": round(import_s, 2),
        "check_s": round(check_s, 2),
        "samples_per_s": round(report.samples / import_s),
        "rows_per_s": round(rows / import_s),
    }


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--samples", type=int, default=10_000_000, help="samples in the QuantumLeap table (default 10M)")
    p.add_argument("--target", choices=["duckdb", "postgresql"], default="duckdb", help="our store (default duckdb)")
    p.add_argument("--json", metavar="FILE", help="also write the figures as JSON")
    args = p.parse_args()
    result = run(args.samples, args.target)
    print(
        f"imported {result['samples']:,} samples ({result['rows']:,} rows) into {result['target']} "
        f"in {result['import_s']} s: {result['samples_per_s']:,} samples/s, {result['rows_per_s']:,} rows/s "
        f"(final check {result['check_s']} s; table loaded in {result['load_s']} s, not timed)"
    )
    if args.json:
        Path(args.json).write_text(json.dumps(result, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
