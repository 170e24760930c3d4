"""Record batches → CSV or Parquet bytes (or MCAP: ``mcap``), piece by piece.

pyarrow's writers write into a file object; here that object only collects
what each batch produced, so the caller can hand it on (an HTTP body chunk,
a file write) and forget it. A Parquet file is one row group per batch with
its footer at the end; a CSV file is one header line and then the rows.
Memory is one batch and its encoding, whatever the export's size.

CSV: RFC 4180 quoting; times as ``2024-05-01T10:00:00.123456Z`` (ISO 8601,
UTC, microseconds); booleans ``true``/``false``; a null is an empty field
and an empty string is ``""``. A text cell that starts with ``=``, ``+``,
``-``, ``@``, a tab or a carriage return gets a leading ``'`` (OWASP's
advice against CSV injection: a spreadsheet would run it as a formula);
``raw`` writes every cell as stored. The times are formatted here (a cast and two
string kernels) because pyarrow's CSV writer formats zoned timestamps about
five times slower than everything else in the row together.
"""

from __future__ import annotations

import os
import time
from collections.abc import Iterator
from pathlib import Path

import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.csv as pa_csv
import pyarrow.parquet as pq

from tsdb_service.faces.export.pieces import Pieces
from tsdb_service.faces.export.query import ExportFormat
from tsdb_service.faces.export.stream import SCHEMA, SampleStream


def csv_schema(schema: pa.Schema) -> pa.Schema:
    """``schema`` with its first column, the time, as ISO text."""
    return schema.set(0, pa.field("time", pa.string(), nullable=False))


CSV_SCHEMA = csv_schema(SCHEMA)
_FORMULA = r"^[=+\-@\t\r]"  # what a spreadsheet may read as a formula (OWASP CSV injection)


def neutralised(column: pa.Array) -> pa.Array:
    """Text cells a spreadsheet would run as formulas, prefixed with ``'``."""
    risky = pc.match_substring_regex(column, _FORMULA)
    if not pc.any(risky).as_py():
        return column
    return pc.if_else(risky, pc.binary_join_element_wise("'", column, ""), column)


def iso_times(times: pa.Array) -> pa.Array:
    """UTC timestamps (µs) → ``2024-05-01T10:00:00.123456Z``."""
    text = times.cast(pa.timestamp("us")).cast(pa.string())  # 2024-05-01 10:00:00.123456
    return pc.binary_join_element_wise(pc.replace_substring(text, " ", "T", max_replacements=1), "Z", "")


class Encoder:
    """``encode(batch)`` → the bytes it adds; ``finish()`` → the rest."""

    def __init__(self, fmt: ExportFormat, raw: bool = False, schema: pa.Schema = SCHEMA, tenant: str = "") -> None:
        self._sink = Pieces()
        self._csv = fmt is ExportFormat.CSV
        self._neutralise = self._csv and not raw
        self._schema = csv_schema(schema) if self._csv else schema
        self._text = [i for i, f in enumerate(schema) if i > 0 and pa.types.is_string(f.type)]
        self._mcap = None
        if fmt is ExportFormat.MCAP:  # its own encoder (faces.export.mcap), naming the tenant
            from tsdb_service.faces.export.mcap import McapEncoder

            self._mcap = McapEncoder(tenant)
        elif self._csv:
            self._writer = pa_csv.CSVWriter(self._sink, self._schema)
        else:
            self._writer = pq.ParquetWriter(self._sink, schema, compression="zstd")

    def encode(self, batch: pa.RecordBatch) -> bytes:
        if self._mcap is not None:
            return self._mcap.encode(batch)
        if batch.num_rows:
            if self._csv:
                batch = batch.set_column(0, self._schema.field(0), iso_times(batch.column(0)))
            if self._neutralise:
                for i in self._text:
                    batch = batch.set_column(i, self._schema.field(i), neutralised(batch.column(i)))
            self._writer.write_batch(batch)
        return self._sink.take()

    def finish(self) -> bytes:
        if self._mcap is not None:
            return self._mcap.finish()
        self._writer.close()
        return self._sink.take()


def chunks(stream: SampleStream, fmt: ExportFormat, raw: bool = False, tenant: str = "") -> Iterator[bytes]:
    """The encoded export, one piece per batch (blocking: run it in a thread)."""
    encoder = Encoder(fmt, raw, stream.schema, tenant)
    while (batch := stream.next_batch()) is not None:
        piece = encoder.encode(batch)
        if piece:
            yield piece
    yield encoder.finish()


def write_file(
    stream: SampleStream, fmt: ExportFormat, path: str | os.PathLike[str], raw: bool = False, tenant: str = ""
) -> tuple[int, int, float]:
    """Write the export to ``path``; (samples, bytes, seconds).

    It is written to ``path.partial`` and renamed at the end, so an export
    cut short never leaves a complete-looking file behind."""
    target = Path(path)
    partial = target.with_name(target.name + ".partial")
    started = time.perf_counter()
    size = 0
    try:
        with open(partial, "wb") as out:
            for piece in chunks(stream, fmt, raw, tenant):
                out.write(piece)
                size += len(piece)
        os.replace(partial, target)
    except BaseException:
        partial.unlink(missing_ok=True)
        raise
    return stream.rows, size, time.perf_counter() - started
