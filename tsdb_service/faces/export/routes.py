"""``GET /v2/export``: history as a CSV or Parquet download, streamed.

Everything that can fail because of the request (parameters, tenant,
service path) or the database being away fails before the first byte, as
an NGSI error. The body is then produced batch by batch in the threadpool
(``Store.read``: a database read and its encoding per step), so neither the
database nor the encoders ever run on the event loop and memory stays at
about one batch.
If the client goes away the cursor is closed at once.
"""

from __future__ import annotations

from collections.abc import AsyncIterator
from functools import partial

import anyio
from fastapi import APIRouter, Request
from starlette.responses import StreamingResponse

from tsdb_service.faces.export import openapi as export_oa
from tsdb_service.faces.export.encode import Encoder
from tsdb_service.faces.export.query import export_query
from tsdb_service.faces.export.stream import SampleStream, open_export
from tsdb_service.http.store import ServiceStore, store_of
from tsdb_service.http.tenancy import tenant_of

router = APIRouter(tags=["export"])


@router.get(
    "/v2/export",
    summary="Export history as CSV, Parquet or MCAP (one row or message per sample)",
    description=(
        "Parameters: format=csv|parquet|mcap (default csv; mcap: for Foxglove, one channel per entity and "
        "attribute, docs/robots.md), type, id, idPattern, attrs (attribute names), "
        "fromDate, toDate, raw; tenant from Fiware-Service / Fiware-ServicePath. Columns: time (UTC, µs), "
        "entity_id, entity_type, service_path, attribute, ngsi_type, value_number, value_text, "
        "value_bool, value_json (exactly one value column set per sample). CSV text cells starting with "
        "=, +, -, @, tab or CR get a leading ' (CSV injection); raw=true writes them as stored. "
        "bucket=WIDTH (10s, 5min, 1h, 1d ...): one row per series and time bucket (from the epoch, UTC) with "
        "the count, average, minimum, maximum, first and last of its numbers, computed by the database: time "
        "(the bucket's start), entity_id, entity_type, service_path, attribute, n, avg, min, max, first, last."
    ),
    response_class=StreamingResponse,
    **export_oa.EXPORT_SPEC,
)
async def export(request: Request) -> StreamingResponse:
    query = export_query(request.query_params, request.headers, tenant_of(request))
    store = store_of(request)
    stream = await store.read(partial(open_export, store, query), memory_first=False)
    filename = f"tsdb-export{query.format.suffix}"
    return StreamingResponse(
        _body(store, stream, Encoder(query.format, query.raw, stream.schema, query.scope.tenant)),
        media_type=query.format.media_type,
        headers={"Content-Disposition": f'attachment; filename="{filename}"'},
    )


async def _body(store: ServiceStore, stream: SampleStream, encoder: Encoder) -> AsyncIterator[bytes]:
    try:
        while (piece := await store.read(partial(_step, stream, encoder), memory_first=False)) is not None:
            if piece:
                yield piece
        yield await store.read(encoder.finish, memory_first=False)
    finally:
        with anyio.CancelScope(shield=True):  # also when the client went away
            await store.read(stream.close, memory_first=False)


def _step(stream: SampleStream, encoder: Encoder) -> bytes | None:
    """One batch read and encoded; None at the end."""
    batch = stream.next_batch()
    return None if batch is None else encoder.encode(batch)
