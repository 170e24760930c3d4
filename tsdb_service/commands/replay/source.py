"""What a replay sends: stored history as updates, in time order, a bounded piece at a time.

An ``Update`` is what one entity notification held: the samples of one
entity at one instant (its time, service path, id, type and attributes with
their NGSI types and values). They come from

* a store opened directly (``store_updates``): the series are resolved by
  the read seam exactly as an export resolves them, the samples read
  through ``BulkReader.export_batches`` (oldest first, a window of
  ``SORT_ROWS`` samples sorted at a time on DuckDB, a server-side cursor on
  PostgreSQL);
* a running service (``service_updates``): its ``GET /v2/export`` in CSV,
  streamed and parsed batch by batch (a DuckDB file belongs to the process
  that serves it).

Either way memory is a batch and a sort window, whatever the span replayed.
Integers come back as numbers (the export keeps numbers as float64), and
metadata are not replayed (the export holds none).
"""

from __future__ import annotations

import io
import os
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from datetime import UTC, datetime, timedelta
from typing import Any

import orjson
import pyarrow as pa

from tsdb_service.core.query import EntityFilter, Scope, TimeRange
from tsdb_service.read.bulk import EXPORT_COLUMNS
from tsdb_service.read.requests import ExportRead, SeriesSelect
from tsdb_service.storage.store import Store

BATCH_ROWS = 16_384
SORT_ROWS = 200_000  # DuckDB: samples sorted at once (~50 MB at the peak)
TOKEN_VARIABLE = "TSDB_CLIENT_TOKEN"
_EPOCH = datetime(1970, 1, 1, tzinfo=UTC)


@dataclass(frozen=True, slots=True)
class Selection:
    """Which history: a tenant's service paths, entities, attributes, a time span."""

    scope: Scope
    entities: EntityFilter = field(default_factory=EntityFilter)
    attrs: tuple[str, ...] | None = None
    time: TimeRange = field(default_factory=TimeRange)


@dataclass(slots=True)
class Update:
    """The samples of one entity at one instant: ``attrs`` are (name, NGSI type, value)."""

    time: datetime
    service_path: str
    entity_id: str
    entity_type: str
    attrs: list[tuple[str, str, Any]]


class SourceError(RuntimeError):
    """The history cannot be read; one line."""


def store_updates(store: Store, selection: Selection) -> Iterator[Update]:
    """The selection's updates from a store opened here."""
    querier = store.querier()
    refs = querier.series(SeriesSelect(selection.scope, selection.entities, selection.attrs))
    if not refs:
        return
    sids = sorted({ref.sid for ref in refs})
    with querier.export_batches(ExportRead(sids, selection.time, BATCH_ROWS, SORT_ROWS)) as batches:
        yield from _grouped(_rows(iter(batches.next, None)))


def service_updates(url: str, params: Mapping[str, str], headers: Mapping[str, str]) -> Iterator[Update]:
    """The selection's updates from the service at ``url`` (``GET /v2/export``, CSV, streamed)."""
    import httpx
    import pyarrow.csv as pa_csv

    sent = {k: v for k, v in headers.items() if v}
    token = os.environ.get(TOKEN_VARIABLE, "").strip()
    if token:
        sent["Authorization"] = f"Bearer {token}"
    base = url.rstrip("/")
    timeout = httpx.Timeout(60.0, connect=10.0)
    try:
        with httpx.stream(
            "GET", f"{base}/v2/export", params={**params, "format": "csv", "raw": "true"}, headers=sent, timeout=timeout
        ) as answer:
            if answer.status_code != 200:
                answer.read()
                raise SourceError(
                    f"the service at {base} refused the export ({answer.status_code} {answer.text[:200]})"
                )
            reader = pa_csv.open_csv(
                pa.PythonFile(_Stream(answer.iter_raw()), mode="r"),
                read_options=pa_csv.ReadOptions(block_size=1 << 20),
                convert_options=pa_csv.ConvertOptions(
                    column_types=_CSV_TYPES, strings_can_be_null=True, quoted_strings_can_be_null=False
                ),
            )
            yield from _grouped(_rows(reader))
    except httpx.HTTPError as exc:
        raise SourceError(f"cannot read history from {base}: {exc or type(exc).__name__}") from None


class _Stream(io.RawIOBase):
    """An iterator of byte chunks as a readable file (what pyarrow reads CSV from)."""

    def __init__(self, chunks: Iterator[bytes]):
        self._chunks, self._rest = chunks, b""

    def readable(self) -> bool:
        return True

    def readinto(self, buffer) -> int:
        while not self._rest:
            chunk = next(self._chunks, None)
            if chunk is None:
                return 0
            self._rest = chunk
        n = min(len(buffer), len(self._rest))
        buffer[:n], self._rest = self._rest[:n], self._rest[n:]
        return n


def _rows(batches) -> Iterator[tuple]:
    """(time µs, entity id, type, service path, attribute, NGSI type, value) of every sample."""
    for batch in batches:
        columns = batch if isinstance(batch, list) else batch.columns
        if not len(columns[0]):
            continue
        times = columns[0].cast(pa.int64()).to_pylist()  # µs: naive or UTC timestamps, or already µs
        rest = [column.to_pylist() for column in columns[1:]]
        for at, row in zip(times, zip(*rest, strict=True), strict=True):
            entity_id, entity_type, service_path, attr, ngsi_type, num, txt, flag, js = row
            yield at, entity_id, entity_type, service_path, attr, ngsi_type, _value(num, txt, flag, js)


def _value(num, txt, flag, js) -> Any:
    if js is not None:
        return orjson.loads(js)
    if num is not None:
        return num
    return txt if txt is not None else flag


def _grouped(rows: Iterator[tuple]) -> Iterator[Update]:
    """Consecutive samples of one entity at one instant as one update (the
    export orders by time, then notification, then series)."""
    current: Update | None = None
    key = None
    for at, entity_id, entity_type, service_path, attr, ngsi_type, value in rows:
        this = (at, service_path, entity_id, entity_type)
        if this != key or current is None or any(a[0] == attr for a in current.attrs):
            if current is not None:
                yield current
            key = this
            current = Update(_EPOCH + timedelta(microseconds=at), service_path, entity_id, entity_type, [])
        current.attrs.append((attr, ngsi_type or "", value))
    if current is not None:
        yield current


# The export's CSV columns as typed values (docs/operations.md, "Export").
_CSV_TYPES = {
    name: pa.timestamp("us", tz="UTC")
    if name == "time"
    else pa.float64()
    if name == "value_number"
    else pa.bool_()
    if name == "value_bool"
    else pa.string()
    for name in EXPORT_COLUMNS
}
