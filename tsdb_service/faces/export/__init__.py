"""Export history to CSV or Parquet: ``GET /v2/export`` and ``tsdb-service export``.

One row per stored sample (long format), in ``stream.SCHEMA``: ``time``
(UTC, microseconds), ``entity_id``, ``entity_type``, ``service_path``,
``attribute``, ``ngsi_type`` and four value columns of which exactly one
is set (``value_number``, ``value_text``, ``value_bool``, ``value_json``).

    query = export_query(params, headers, tenant)     # parse (400 on bad input)
    with open_export(store, query) as stream:         # blocking: in a thread
        for piece in chunks(stream, query.format):
            ...
"""

from tsdb_service.faces.export.encode import Encoder, chunks, write_file
from tsdb_service.faces.export.query import ExportFormat, ExportQuery, export_format, export_query
from tsdb_service.faces.export.routes import router
from tsdb_service.faces.export.stream import SCHEMA, SampleStream, open_export

__all__ = [
    "SCHEMA",
    "Encoder",
    "ExportFormat",
    "ExportQuery",
    "SampleStream",
    "chunks",
    "export_format",
    "export_query",
    "open_export",
    "router",
    "write_file",
]
