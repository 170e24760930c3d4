"""``GET /v2/export``: history as a CSV or Parquet download, streamed.

Everything that can fail because of the request (parameters, tenant,
service path) or the database being away fails before the first byte, as
an NGSI error. The body is then produced batch by batch in the threadpool
(a database read and its encoding per step), so neither DuckDB nor the
encoders ever run on the event loop and memory stays at about one batch.
If the client goes away the cursor is closed at once.
"""

from __future__ import annotations

from collections.abc import AsyncIterator

import anyio
from fastapi import APIRouter, Request
from starlette.concurrency import run_in_threadpool
from starlette.responses import StreamingResponse

from ..export import Encoder, SampleStream, export_query, open_export
from . import openapi as oa
from .tenancy import tenant_of

router = APIRouter(tags=["export"])


@router.get(
    "/v2/export",
    summary="Export history as CSV or Parquet (one row per sample)",
    description=(
        "Parameters: format=csv|parquet (default csv), type, id, idPattern, attrs (attribute names), "
        "fromDate, toDate; tenant from Fiware-Service / Fiware-ServicePath. Columns: time (UTC, µs), "
        "entity_id, entity_type, service_path, attribute, ngsi_type, value_number, value_text, "
        "value_bool, value_json (exactly one value column set per sample)."
    ),
    response_class=StreamingResponse,
    **oa.EXPORT_SPEC,
)
async def export(request: Request) -> StreamingResponse:
    query = export_query(request.query_params, request.headers, tenant_of(request))
    stream = await run_in_threadpool(open_export, request.app.state.store, query)
    filename = f"tsdb-export{query.format.suffix}"
    return StreamingResponse(
        _body(stream, Encoder(query.format)),
        media_type=query.format.media_type,
        headers={"Content-Disposition": f'attachment; filename="{filename}"'},
    )


async def _body(stream: SampleStream, encoder: Encoder) -> AsyncIterator[bytes]:
    try:
        while (piece := await run_in_threadpool(_step, stream, encoder)) is not None:
            if piece:
                yield piece
        yield await run_in_threadpool(encoder.finish)
    finally:
        with anyio.CancelScope(shield=True):  # also when the client went away
            await run_in_threadpool(stream.close)


def _step(stream: SampleStream, encoder: Encoder) -> bytes | None:
    """One batch read and encoded; None at the end."""
    batch = stream.next_batch()
    return None if batch is None else encoder.encode(batch)
